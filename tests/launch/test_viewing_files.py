"""The Foxglove layout shows what the cell records, and the docs do not send users outside the repository."""
from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]


def _recorded_topics() -> set[str]:
    cell = yaml.safe_load((REPO / "src" / "stud_bringup" / "config" / "cell.yaml").read_text())
    return {a for a in cell["nodes"]["bag_record"]["cmd"] if a.startswith("/")}


def test_the_cell_bag_holds_tf_and_the_robot_model():
    assert {"/tf", "/tf_static", "/robot_description"} <= _recorded_topics()


def test_every_topic_the_foxglove_layout_shows_is_in_the_cell_bag():
    layout = json.loads((REPO / "docs" / "foxglove_layout.json").read_text())
    text = json.dumps(layout["configById"])
    shown = {t.split(".")[0] for t in re.findall(r'"(/[a-z_/]+(?:\.[a-z_]+)?)"', text)}
    assert {"/robot_description", "/weld_targets/markers", "/weld_targets/overlay/compressed", "/cell/status"} <= shown
    assert shown <= _recorded_topics()
    panels = {key.split("!")[0] for key in layout["configById"]}
    assert {"3D", "Image", "RawMessages"} <= panels


def test_repository_docs_do_not_link_to_documents_users_do_not_have():
    docs = [REPO / "README.md", *REPO.glob("docs/*.md"), *REPO.glob("src/*/README.md")]
    for doc in docs:
        text = doc.read_text()
        assert "../shared" not in text and "/work/shared" not in text, doc
