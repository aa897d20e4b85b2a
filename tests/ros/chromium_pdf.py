"""Headless Chromium for the tests that print a page (the QA record): where it is, and a page printed
to PDF with its page count."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path


def find_chromium() -> str | None:
    """The Chromium binary (CHROMIUM=/path chooses one), or None."""
    candidates = [os.environ.get("CHROMIUM")] + [shutil.which(n) for n in (
        "chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


def print_to_pdf(chromium: str, page: Path, work_dir: Path) -> tuple[int, bytes]:
    """(pages, PDF bytes) of ``page`` printed by headless Chromium (paper: the page's own @page rule)."""
    pdf = work_dir / (page.stem + ".pdf")
    subprocess.run([chromium, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    "--disable-dev-shm-usage", f"--user-data-dir={work_dir / 'chromium-profile'}",
                    "--no-pdf-header-footer", f"--print-to-pdf={pdf}", page.as_uri()],
                   check=True, capture_output=True, timeout=120)
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF")
    pages = len(re.findall(rb"/Type\s*/Page(?![s\w])", data))
    count = re.search(rb"/Type\s*/Pages\b.*?/Count\s+(\d+)", data, re.S)
    assert count is None or int(count.group(1)) == pages  # the page tree agrees
    return pages, data
