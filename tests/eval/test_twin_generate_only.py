"""`alacs-twin generate --only`: the named cases alone, rendered exactly as in the whole set,
the others left untouched; a name the set does not hold is refused."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
from pathlib import Path

import pytest


def _twin() -> str:
    tw = os.environ.get("ALACS_TWIN")
    if not tw:
        pytest.fail("set ALACS_TWIN to the alacs-twin binary (tests/eval/run.sh does)")
    return tw


def _generate(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([_twin(), "generate", "--set", "lle", "--count", "3", "--seed", "5", "--world",
                           "benchmark-hard", "--out", str(out), "--jobs", "2", *extra],
                          capture_output=True, text=True, timeout=300)


def _digests(case: Path) -> dict[str, str]:
    return {str(p.relative_to(case)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(case.rglob("*")) if p.is_file()}


def _index(out: Path) -> list[dict]:
    return [json.loads(l) for l in (out / "set.jsonl").read_text().splitlines() if l.strip()]


def test_only_renders_the_named_cases_as_the_whole_set_does(tmp_path):
    whole = tmp_path / "whole"
    assert _generate(whole).returncode == 0
    before = _digests(whole / "lle_0001")
    index = _index(whole)
    # The stored case 0 is left as it is; case 1 is rendered again into the same set, where
    # it had been damaged, and comes out as the whole set rendered it.
    (whole / "lle_0000" / "untouched").write_text("kept")
    (whole / "lle_0001" / "manifest.json").write_text("damaged")
    one = _generate(whole, "--only", "lle_0001")
    assert one.returncode == 0, one.stderr
    assert [json.loads(l)["case"] for l in one.stdout.splitlines()] == ["lle_0001"]
    assert (whole / "lle_0000" / "untouched").read_text() == "kept"
    assert _digests(whole / "lle_0001") == before
    assert _index(whole) == index  # the set's index: every case, in order
    # Into an empty directory: that case alone, and an index of it alone.
    alone = tmp_path / "alone"
    assert _generate(alone, "--only", "lle_0002").returncode == 0
    assert sorted(p.name for p in alone.iterdir()) == ["lle_0002", "set.jsonl"]
    assert [c["case"] for c in _index(alone)] == ["lle_0002"]
    assert _digests(alone / "lle_0002") == _digests(whole / "lle_0002")


@pytest.mark.parametrize("only, extra, why", [
    ("lle_0001,d1000_occ1_0000", (), "no case 'd1000_occ1_0000'"),
    ("lle_0001,lle_0001", (), "named twice"),
    ("", (), "no case named"),
    ("lle_0001", ("--resume",), "does not go with --resume"),
], ids=["not in the set", "twice", "empty", "with resume"])
def test_a_list_that_cannot_be_rendered_as_asked_is_refused(tmp_path, only, extra, why):
    r = _generate(tmp_path / "out", "--only", only, *extra)
    assert r.returncode == 2
    assert why in r.stderr
    assert not (tmp_path / "out" / "lle_0001").exists()


def test_a_case_of_a_set_made_with_another_seed_is_refused(tmp_path):
    out = tmp_path / "out"
    assert _generate(out, "--only", "lle_0001").returncode == 0
    index = (out / "set.jsonl").read_text()
    r = subprocess.run([_twin(), "generate", "--set", "lle", "--count", "3", "--seed", "6", "--world",
                        "benchmark-hard", "--out", str(out), "--only", "lle_0001"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    assert "another seed" in r.stderr
    assert (out / "set.jsonl").read_text() == index


def test_resume_keeps_the_cases_already_written(tmp_path):
    # (--resume was read as "true" -> 0 and never kept anything, until the flags' text was fixed.)
    out = tmp_path / "out"
    assert _generate(out, "--only", "lle_0000").returncode == 0
    (out / "lle_0000" / "manifest.json").write_text("kept")
    r = _generate(out, "--resume")
    assert r.returncode == 0, r.stderr
    assert (out / "lle_0000" / "manifest.json").read_text() == "kept"
    assert (out / "lle_0002" / "manifest.json").exists()
    assert [c["case"] for c in _index(out)] == ["lle_0000", "lle_0001", "lle_0002"]
