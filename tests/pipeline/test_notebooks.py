"""The quickstart notebook on a tiny agent trained here, and the notebook runner's metadata stripping.

The pipeline notebooks (and the quickstart on the pipeline's own agent) run in tests/pipeline/test_pipeline.py.
"""

from __future__ import annotations

import copy
import os
import sys
from pathlib import Path

import nbformat
import pytest

from paper_lib.pipeline.notebook_run import run_notebook, strip_run_metadata

REPO = Path(__file__).resolve().parents[2]
QUICKSTART = REPO / "notebooks" / "00_quickstart.ipynb"


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory) -> Path:
    from paper_lib.agents.training import train_run

    out = tmp_path_factory.mktemp("agent") / "HalfCheetah-v5" / "masksembles" / "seed0"
    return train_run("HalfCheetah-v5", "masksembles", 0, out, total_timesteps=256, resume=False,
                     agent_kwargs={"overrides": {"n_steps": 16, "batch_size": 32, "n_epochs": 1}})


def _outputs(nb: nbformat.NotebookNode) -> list:
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]


@pytest.fixture
def on_path(monkeypatch):
    """The kernel papermill starts must find this interpreter's packages."""
    monkeypatch.setenv("PATH", f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("MPLBACKEND", "Agg")


def test_quickstart_on_a_tiny_agent_shows_uncertainty_against_detectors(tiny_checkpoint, tmp_path, on_path):
    out = run_notebook(QUICKSTART, tmp_path / "quickstart.ipynb",
                       {"checkpoint": str(tiny_checkpoint), "live": True, "n_id_states": 40, "episode_steps": 30,
                        "frames": 3, "figures_dir": str(tmp_path / "figures")})
    outputs = _outputs(nbformat.read(out, as_version=4))
    assert not [o for o in outputs if o.output_type in ("error",) or (o.output_type == "stream" and o.name == "stderr")]
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    text = "\n".join(o.get("data", {}).get("text/markdown", "") for o in outputs)
    assert "masksembles" in text and "flags" in text  # the computed summary of the run
    assert (tmp_path / "figures" / "quickstart_timeline.png").stat().st_size > 0
    from paper_lib.reporting.rendering import mujoco_rendering_problem

    if mujoco_rendering_problem() is None:  # EGL works: timeline and frames; without it, a note instead of frames
        assert len(images) == 2 and (tmp_path / "figures" / "quickstart_frames.png").is_file()
    else:
        assert len(images) == 1 and "No frames" in text


def test_quickstart_from_its_recording_shows_what_playing_it_live_shows(tiny_checkpoint, tmp_path, on_path):
    """A rebuild draws the recorded episode (never steps an env); on the recording's machine that is the live picture."""
    from paper_lib.experiments.recordings import play_gravity_change, quickstart_settings, save_gravity_episode

    played = (tiny_checkpoint, 30, 15, [0.0, 0.0, -1.0], 40, 0, 0)  # folder, steps, change_at, gravity, states, seed, frames
    recording = save_gravity_episode(tmp_path / "quickstart.npz", quickstart_settings(*played), play_gravity_change(*played))
    params = {"checkpoint": str(tiny_checkpoint), "n_id_states": 40, "episode_steps": 30, "frames": 0}
    live = run_notebook(QUICKSTART, tmp_path / "live.ipynb", {**params, "live": True})
    recorded = run_notebook(QUICKSTART, tmp_path / "recorded.ipynb", {**params, "recording": str(recording)})
    outputs = _outputs(nbformat.read(recorded, as_version=4))
    assert outputs == _outputs(nbformat.read(live, as_version=4)) and any("image/png" in o.get("data", {}) for o in outputs)
    with pytest.raises(Exception, match=r"recorded with other settings \(episode_steps is 30, wanted 20; change_at is 15, "
                                        r"wanted 10\).*make recollect"):
        run_notebook(QUICKSTART, tmp_path / "other.ipynb", {**params, "episode_steps": 20, "recording": str(recording)})


def test_quickstart_from_its_recording_ranks_the_recorded_scores(tiny_checkpoint, tmp_path, on_path):
    """A rebuild computes no score (torch and BLAS round differently on other CPUs): it ranks the recorded ones. Every
    recorded calibration score of value_std set below the episode's puts each of its steps at the 100th ID percentile."""
    import json

    import numpy as np

    from paper_lib.common.recordings import save_recording
    from paper_lib.experiments.recordings import play_gravity_change, quickstart_settings, save_gravity_episode

    played = (tiny_checkpoint, 30, 15, [0.0, 0.0, -1.0], 40, 0, 0)
    recording = save_gravity_episode(tmp_path / "quickstart.npz", quickstart_settings(*played), play_gravity_change(*played))
    with np.load(recording) as data:
        arrays = {name: data[name] for name in data.files if name != "settings"}
        settings = json.loads(str(data["settings"]))
    arrays["calibration__value_std"] = np.full_like(arrays["calibration__value_std"], -np.inf)
    save_recording(recording, settings, **arrays)
    out = run_notebook(QUICKSTART, tmp_path / "recorded.ipynb", {"checkpoint": str(tiny_checkpoint), "n_id_states": 40,
                                                                  "episode_steps": 30, "frames": 0,
                                                                  "recording": str(recording)})
    text = "\n".join(o.get("data", {}).get("text/markdown", "") for o in _outputs(nbformat.read(out, as_version=4)))
    assert "the best member measure, **value_std**, flags 100% (before: 100%)" in text, text


def test_quickstart_names_a_wrong_checkpoint_folder(tmp_path, on_path):
    with pytest.raises(Exception, match="is not a checkpoint folder"):
        run_notebook(QUICKSTART, tmp_path / "out.ipynb", {"checkpoint": str(tmp_path / "nowhere"), "frames": 0})
    assert not (tmp_path / "out.ipynb").exists()


def test_strip_run_metadata_keeps_outputs_and_drops_timestamps():
    nb = nbformat.v4.new_notebook(metadata={"papermill": {"start_time": "2026-01-01T00:00:00", "duration": 3.2},
                                            "kernelspec": {"name": "python3", "display_name": "Python 3"}})
    cell = nbformat.v4.new_code_cell("1 + 1", execution_count=1,
                                     outputs=[nbformat.v4.new_output("execute_result", {"text/plain": "2"},
                                                                     execution_count=1)])
    cell.metadata.update({"papermill": {"duration": 0.1, "status": "completed"}, "tags": ["parameters"],
                          "execution": {"iopub.execute_input": "2026-01-01T00:00:00"}})
    nb.cells = [cell, nbformat.v4.new_markdown_cell("text")]
    other = copy.deepcopy(nb)
    other.metadata["papermill"]["duration"] = 9.9
    other.cells[0].metadata["execution"]["iopub.execute_input"] = "2027-01-01T00:00:00"
    other.cells[0]["id"], other.cells[1]["id"] = "random-a", "random-b"
    stripped = strip_run_metadata(nb)
    assert nbformat.writes(stripped) == nbformat.writes(strip_run_metadata(other))
    assert "papermill" not in stripped.metadata and stripped.metadata["kernelspec"]["name"] == "python3"
    kept = stripped.cells[0]
    assert kept.outputs[0]["data"]["text/plain"] == "2" and kept.execution_count == 1
    assert kept.metadata == {"tags": ["parameters"]}


def test_notebook_runner_refuses_a_missing_notebook(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        run_notebook(tmp_path / "missing.ipynb", tmp_path / "out.ipynb")
    with pytest.raises(ValueError, match=".ipynb file"):
        run_notebook(QUICKSTART, tmp_path / "out.txt")


def test_the_runner_drops_tqdms_widget_warning_and_keeps_other_warnings(tmp_path, on_path):
    """tqdm.auto without ipywidgets warns with the venv's absolute path: two clones would write different notebooks."""
    nb = nbformat.v4.new_notebook(metadata={"kernelspec": {"name": "python3", "display_name": "Python 3",
                                                           "language": "python"}})
    nb.cells = [nbformat.v4.new_code_cell(
        "import warnings\n"
        "warnings.warn('IProgress not found. Please update jupyter and ipywidgets.')\n"
        "warnings.warn('a warning that says something')")]
    source = tmp_path / "warns.ipynb"
    nbformat.write(nb, source)
    text = "".join(o.get("text", "") for o in _outputs(nbformat.read(run_notebook(source, tmp_path / "out.ipynb"), 4)))
    assert "a warning that says something" in text and "IProgress" not in text


@pytest.mark.parametrize("path", sorted((REPO / "notebooks").glob("*.ipynb")), ids=lambda p: p.name)
def test_every_notebook_is_valid_nbformat_with_its_own_cell_ids(path):
    """nbformat 4.5 wants a unique id on every cell; a cell without one gets a random id (and a warning) each time a
    tool reads it, and Jupyter's next save writes those random ids into the committed notebook."""
    import json

    raw = json.loads(path.read_text())
    ids = [cell.get("id") for cell in raw["cells"]]
    assert None not in ids and len(set(ids)) == len(ids), ids
    nbformat.validate(nbformat.from_dict(raw))
