"""The suite's own rules (tests/conftest.py): what a CI run may not skip, and how property tests run."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from hypothesis import settings

TESTS = Path(__file__).resolve().parent


def test_the_ci_profile_is_derandomised_with_a_hundred_examples_and_chosen_by_ci_true():
    ci = settings.get_profile("ci")
    assert ci.derandomize and ci.max_examples >= 100 and ci.database is None
    if os.environ.get("CI", "").lower() == "true" and not os.environ.get("HYPOTHESIS_PROFILE"):
        assert settings.default.max_examples >= 100 and settings.default.derandomize


def _run_probe(tmp_path: Path, ci: bool) -> subprocess.CompletedProcess:
    """A throw-away test that needs a missing corpus, run with and without CI=true."""
    probe = tmp_path / "test_probe.py"
    probe.write_text("def test_needs_the_corpus(require_shared_data):\n"
                     "    require_shared_data('/nonexistent/shared/data/dxf')\n")
    (tmp_path / "conftest.py").write_text((TESTS / "conftest.py").read_text())
    env = {k: v for k, v in os.environ.items() if k not in ("CI", "HYPOTHESIS_PROFILE")}
    if ci:
        env["CI"] = "true"
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider", str(probe)],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)


def test_a_missing_corpus_skips_with_its_reason_locally_and_fails_under_ci(tmp_path):
    local = _run_probe(tmp_path, ci=False)
    assert local.returncode == 0 and "1 skipped" in local.stdout
    assert "/nonexistent/shared/data/dxf is not on this machine" in local.stdout
    ci = _run_probe(tmp_path, ci=True)
    assert ci.returncode == 1 and "1 failed" in ci.stdout
    assert "CI=true: a missing prerequisite fails the run" in ci.stdout


def test_the_code_passes_the_linter():
    """ruff.toml's rules over src/, tests/, tools/ and bench/: no unused import or variable, no undefined
    or shadowed name. Run `ruff check` to see the findings, `ruff check --fix` fixes most."""
    ruff = Path(sys.executable).with_name("ruff")
    done = subprocess.run([str(ruff), "check", "--output-format", "concise", "src", "tests", "tools", "bench"],
                          cwd=TESTS.parent, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
