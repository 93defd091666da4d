"""A damaged JSON file the rig reads (a simulation config, a replay's metrics, a bench
baseline, a combine-models config) is refused in one line that names it."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from rigtest import ROOT, run_rig

from rig.data.errors import InputError, JsonFileError, read_json


def test_read_json_names_the_file_it_cannot_parse(tmp_path: Path) -> None:
    good, bad = tmp_path / "good.json", tmp_path / "bad.json"
    good.write_text('{"a": [1, 2]}')
    bad.write_text('{"a": [1, ')
    assert read_json(good) == {"a": [1, 2]}
    with pytest.raises(JsonFileError, match=r"bad\.json is not valid JSON") as err:
        read_json(bad)
    assert isinstance(err.value, InputError)
    with pytest.raises(FileNotFoundError):
        read_json(tmp_path / "missing.json")


def test_the_cli_refuses_damaged_json_in_one_line_naming_it(tmp_path: Path) -> None:
    (tmp_path / "sim.json").write_text('{"duration": ')
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    shutil.copy(ROOT / "recordings" / "default.mcap", run_dir / "run.mcap")
    (run_dir / "metrics.json").write_text("{")
    for args, named in ((("simulate", "-o", str(tmp_path / "x.mcap"), "--config", str(tmp_path / "sim.json")),
                         tmp_path / "sim.json"),
                        (("report", str(run_dir)), run_dir / "metrics.json")):
        proc = run_rig(*args)
        assert proc.returncode == 2, proc.stderr
        assert f"{named} is not valid JSON" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.mcap").exists() and not (run_dir / "report.html").exists()
