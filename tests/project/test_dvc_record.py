"""scripts/dvc_record.py records stages whose outputs are known unchanged, like `dvc commit -f` but in one pass."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "dvc_record.py"
BIN = Path(sys.executable).parent


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, env={"PATH": f"{BIN}:/usr/bin:/bin",
                                                                             "DVC_NO_ANALYTICS": "1", "HOME": str(cwd)})


def test_a_renamed_command_is_recorded_without_running_it(tmp_path):
    for args in (["git", "init", "-q"], [str(BIN / "dvc"), "init", "-q"]):
        assert _run(args, tmp_path).returncode == 0
    (tmp_path / "a.txt").write_text("data\n")
    stage = "stages:\n  copy:\n    cmd: {cmd}\n    deps: [a.txt]\n    outs:\n      - b.txt: {{cache: false}}\n"
    (tmp_path / "dvc.yaml").write_text(stage.format(cmd="cp a.txt b.txt"))
    assert _run([str(BIN / "dvc"), "repro", "-q"], tmp_path).returncode == 0
    (tmp_path / "dvc.yaml").write_text(stage.format(cmd="cp -p a.txt b.txt"))  # the same work, another command
    assert "changed command" in _run([str(BIN / "dvc"), "status"], tmp_path).stdout
    (tmp_path / "stages.txt").write_text("copy\n")
    done = _run([sys.executable, str(SCRIPT), "stages.txt"], tmp_path)
    assert done.returncode == 0, done.stderr
    assert "recorded 1 stage(s)" in done.stdout
    assert "up to date" in _run([str(BIN / "dvc"), "status"], tmp_path).stdout
    (tmp_path / "stages.txt").write_text("copy\ncopi\n")
    typo = _run([sys.executable, str(SCRIPT), "stages.txt"], tmp_path)
    assert typo.returncode != 0 and "does not have: ['copi']" in typo.stderr
