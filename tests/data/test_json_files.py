"""A damaged JSON file the rig reads (a simulation config, a replay's metrics, a bench
baseline, a combine-models config) is refused in one line that names it; a file the rig
writes (a model, a report) is written whole or not at all."""

from __future__ import annotations

import shutil
import subprocess
import sys
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


# A real failed write: the process may write files of at most 4 kB (RLIMIT_FSIZE; the
# signal that would kill it ignored, so the write fails with EFBIG), then saves a model
# (about 30 kB) over an older one.
_SAVE_WITH_A_FILE_SIZE_LIMIT = """
import resource, signal, sys
from rig.data.paths import SHIPPED_BIAS_NET
from rig.estimator.bias_net import BiasNet
model = BiasNet.load(SHIPPED_BIAS_NET)
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
try:
    model.save(sys.argv[1])
except OSError as exc:
    print(exc)
"""


def test_a_model_that_cannot_be_written_whole_leaves_the_old_one(tmp_path: Path) -> None:
    model = tmp_path / "bias_net.json"
    model.write_text("the old model")
    proc = subprocess.run([sys.executable, "-c", _SAVE_WITH_A_FILE_SIZE_LIMIT, str(model)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert f"cannot write {model}: File too large" in proc.stdout
    assert model.read_text() == "the old model" and [p.name for p in tmp_path.iterdir()] == ["bias_net.json"]
