"""Train several matrix runs at once on a lent GPU machine, within its short lease, and bring them back.

A lent machine (16 cores, one GPU) is held for minutes, and one call returns at most 8 files of 16 MiB
(64 MiB in all). So, on the machine:

    python scripts/gpu_runs.py launch WORK ENV METHOD SEED [ENV METHOD SEED ...]   # returns at once
    python scripts/gpu_runs.py launch WORK --queue FILE          # or the paper_lib.agents.training lines of a queue file
    python scripts/gpu_runs.py watch WORK --until 540 --stop     # progress every 30 s, then stop the runs
    python scripts/gpu_runs.py pack WORK --out $OUT               # again, in quick calls, until none is left

`launch` starts each run as `python -m paper_lib.agents.training ... --device cuda --env-processes` in its own
process session, so it outlives the call. `--queue` takes the lines the queue commands print
(`python -m paper_lib.pipeline.status queue`, `python -m paper_lib.experiments.ensembles queue`), so any run goes
with its own checkpoint folder and arguments (an independent ensemble member's `--timesteps 250000
--hp algo.n_epochs=16`, an `own` run's `--assignment own`). `pack` sends what the runs reached: a
finished run as its checkpoint folder (~4 MB), an unfinished one as its resume point (~20 MB with
Adam's moments, ~80 MB for an Atari Ensemble), each a tar cut into 15 MiB parts
(`NAME.{checkpoint,resume}.tar.partIIofNN`, NAME the folder below results/), as many parts as one call
returns; a tar that does not fit continues in the next call. Here, `unpack` joins the parts of all the
calls' folders and puts them in place: checkpoints into the repository, resume points under the resume
root, where `scripts/train_queue.sh` continues them on this machine's CPUs (config.json's `segments`
then says which steps ran where).

The runs import a copy of paper_lib and params.yaml (WORK/code): a later call replaces the working tree.
Measured on leases (Atari, 8 envs a run): H100, 2026-11-24, envs stepped in the run's own process:
14 runs at once ~370 steps/s each, 5 at once ~520. H200, 2026-11-26, `--env-processes`: 8 runs at once
~850 steps/s each (MC Dropout ~650), 4 at once the same (the bound is each run's own loop, not the
cores), the first resume point after ~90 s of start-up. H100, 2026-11-26, `--env-processes`: the ten Atari
independent-ensemble members (16 epochs) at once ~280 steps/s each, 128,000 steps in 520 s; ten ~20 MB
resume points took four more calls (~20 s each) to come back. A 1e6-step Atari run needs ~20 min: more than
one call (10 min), so runs come back as resume points and finish here.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

#: The profile whose checkpoints `launch ENV METHOD SEED` trains (the main matrix's).
PROFILE = "paper"
CHECK_EVERY = 30
RESUME_EVERY = 25_000  # finer progress readings than the default 50k
MAX_FILES, MAX_BYTES = 8, 60 * 2**20  # what one call of the lent machine returns (64 MiB), with room
PART_BYTES = 15 * 2**20
PART_NAME = re.compile(r"(?P<name>.+)\.(?P<kind>checkpoint|resume)\.tar\.part(?P<index>\d+)of(?P<total>\d+)")


def state_file(work: Path) -> Path:
    return work / "runs.json"


def load_state(work: Path) -> dict:
    return json.loads(state_file(work).read_text())


def save_state(work: Path, state: dict) -> None:
    state_file(work).write_text(json.dumps(state, indent=1))


def layout_module():
    """paper_lib/pipeline/layout.py of this repository, loaded as a file: the paths' one home imports nothing of
    paper_lib, and this script runs no torch (the package's __init__ imports it)."""
    name = "_gpu_runs_layout"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "paper_lib" /
                                                      "pipeline" / "layout.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module  # dataclasses look their module up there
        spec.loader.exec_module(module)
    return sys.modules[name]


def checkpoint_dir(run: dict) -> Path:
    """The run's checkpoint folder, relative to the repository (as on its queue line)."""
    return Path(run["folder"])


def run_name(run: dict) -> str:
    """A file name unique across trees: the folder below results/, without the `checkpoints` level."""
    layout = layout_module()
    parts = [p for p in checkpoint_dir(run).parts if p not in (layout.RESULTS, layout.RUN_FOLDERS["checkpoint"])]
    return "_".join(parts)


def main_matrix_run(env_id: str, method: str, seed: int) -> dict:
    """A run of the main matrix, at its usual folder with the env's own settings."""
    return {"env": env_id, "method": method, "seed": seed,
            "folder": str(layout_module().Layout.of(".", PROFILE).checkpoint_dir(env_id, method, seed)), "extra": []}


def queued_run(line: str) -> dict:
    """A run from a queue line `... -m paper_lib.agents.training ENV METHOD SEED FOLDER [ARGS ...]`."""
    words = line.split()
    try:
        env_id, method, seed, folder, *extra = words[words.index("paper_lib.agents.training") + 1:]
        seed_number = int(seed)
    except ValueError:
        raise ValueError(f"not a queue line (`... -m paper_lib.agents.training ENV METHOD SEED FOLDER [ARGS]`): {line!r}; "
                         "take lines from `python -m paper_lib.pipeline.status queue` or "
                         "`python -m paper_lib.experiments.ensembles queue`") from None
    if Path(folder).is_absolute():
        raise ValueError(f"queue line with an absolute checkpoint folder {folder!r}: the folder must be relative to "
                         "the repository, as the queue commands print it")
    return {"env": env_id, "method": method, "seed": seed_number, "folder": folder, "extra": extra}


def read_queue(path: Path) -> list[dict]:
    """The runs of a queue file's lines not yet marked (lines starting with `#` are done or taken)."""
    lines = [line.strip() for line in path.read_text().splitlines()]
    return [queued_run(line) for line in lines if line and not line.startswith("#")]


def resume_point(work: Path, run: dict) -> Path:
    """Where paper_lib.agents.training keeps the run's resume point (PAPER_LIB_RESUME_ROOT=WORK/resume)."""
    return work / "resume" / (work / checkpoint_dir(run)).relative_to("/")


def launch(work: Path, runs: list[dict], repo: Path, device: str = "cuda",
           timesteps: int | None = None, resume_every: int = RESUME_EVERY) -> None:
    """Start every run in its own session and record its pid (beside the runs of an earlier launch).

    ``timesteps``, when given, replaces the runs' budgets (their own `--timesteps` included).
    """
    work = work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    code = work / "code"
    if not code.exists():  # later calls replace the working tree under the running runs
        shutil.copytree(repo / "paper_lib", code / "paper_lib", ignore=shutil.ignore_patterns("__pycache__"))
        shutil.copy2(repo / "params.yaml", code / "params.yaml")
    env = {**os.environ, "PAPER_LIB_RESUME_ROOT": str(work / "resume"), "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(filter(None, [str(code), os.environ.get("PYTHONPATH")]))}
    state = load_state(work) if state_file(work).is_file() else {"launched": time.time(), "runs": []}
    for queued in runs:
        run = {**queued, "status": "running"}
        cmd = [sys.executable, "-m", "paper_lib.agents.training", run["env"], run["method"], str(run["seed"]),
               str(work / checkpoint_dir(run)), *run["extra"],
               "--device", device, "--env-processes", "--resume-every", str(resume_every)]
        if timesteps is not None:
            cmd += ["--timesteps", str(timesteps)]
        log = open(work / f"{run_name(run)}.log", "w")
        proc = subprocess.Popen(cmd, cwd=code, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        run["pid"] = proc.pid
        state["runs"].append(run)
        print(f"started {run_name(run)} {' '.join(run['extra'])} (pid {proc.pid})", flush=True)
    save_state(work, state)


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def progress(work: Path, run: dict) -> int:
    """The step count of the run's last resume point (0 before the first)."""
    try:
        with open(resume_point(work, run) / "state.pkl", "rb") as f:
            return int(pickle.load(f)["num_timesteps"])
    except (OSError, EOFError, pickle.UnpicklingError, KeyError):
        return 0


def refresh(work: Path, state: dict) -> None:
    """Mark the runs that finished (their checkpoint is written) or crashed."""
    for run in state["runs"]:
        if run["status"] != "running":
            continue
        if (work / checkpoint_dir(run) / "config.json").is_file():
            run["status"] = "finished"
        elif not alive(run["pid"]):
            run["status"] = "crashed"


def stop(state: dict) -> None:
    """Kill the runs still training, so their last resume points stay as they are while they are packed."""
    for run in state["runs"]:
        if run["status"] == "running":
            os.killpg(run["pid"], signal.SIGKILL)
            run["status"] = "stopped"


def watch(work: Path, until: float, stop_after: bool) -> None:
    work = work.resolve()
    state = load_state(work)
    start = time.time()
    while True:
        refresh(work, state)
        line = ", ".join(f"{r['env'][:8]} {r['method']} " + (str(progress(work, r)) if r["status"] == "running"
                                                               else r["status"]) for r in state["runs"])
        print(f"[{time.time() - state['launched']:.0f} s] {line}", flush=True)
        if all(r["status"] != "running" for r in state["runs"]) or time.time() - start + CHECK_EVERY > until:
            break
        time.sleep(CHECK_EVERY)
    if stop_after:
        stop(state)
    save_state(work, state)
    for run in state["runs"]:
        if run["status"] == "crashed":
            log = work / f"{run_name(run)}.log"
            print(f"--- {log.name} (crashed)\n" + log.read_text()[-2000:], flush=True)


def pack(work: Path, out: Path, max_files: int = MAX_FILES, max_bytes: int = MAX_BYTES) -> None:
    """Send the next parts not yet sent, as many as one call returns; print what is left.

    Each stopped or finished run is one tar (its checkpoint folder, or its resume point) cut into
    PART_BYTES parts named `NAME.KIND.tar.partIIofNN`; a tar larger than one call (an Atari Ensemble's
    resume point is ~80 MB) continues in the next call.
    """
    work = work.resolve()
    state = load_state(work)
    out.mkdir(parents=True, exist_ok=True)
    files, size = 0, 0
    for run in state["runs"]:
        if run.get("packed") or run["status"] == "running":
            continue
        finished = run["status"] == "finished"
        kind, folder = ("checkpoint", work / checkpoint_dir(run)) if finished else ("resume", resume_point(work, run))
        if not (folder / ("config.json" if finished else "state.pkl")).is_file():
            run["packed"] = "nothing"  # stopped before its first resume point
            continue
        blob = work / "packs" / f"{run_name(run)}.{kind}.tar"
        if not blob.is_file():  # made once: parts sent by earlier calls stay valid
            blob.parent.mkdir(exist_ok=True)
            with tarfile.open(blob, "w") as tar:
                tar.add(folder, arcname=str(checkpoint_dir(run)))
        total = -(-blob.stat().st_size // PART_BYTES)
        sent = run.get("parts_sent", 0)
        with open(blob, "rb") as f:
            while sent < total:
                f.seek(sent * PART_BYTES)
                part = f.read(PART_BYTES)
                if files + 1 > max_files or size + len(part) > max_bytes:
                    break
                (out / f"{blob.name}.part{sent + 1:02d}of{total:02d}").write_bytes(part)
                sent, files, size = sent + 1, files + 1, size + len(part)
        run["parts_sent"] = sent
        what = "checkpoint" if finished else f"resume point at step {progress(work, run)}"
        if sent < total:
            print(f"packed {run_name(run)}: {what}, {sent} of {total} parts (the rest in the next call)", flush=True)
            break
        run["packed"] = True
        print(f"packed {run_name(run)}: {what}", flush=True)
    save_state(work, state)
    left = [run_name(r) for r in state["runs"] if not r.get("packed")]
    print(f"left to pack: {left or 'none'}", flush=True)


def joined_parts(folders: list[Path]) -> dict[tuple[str, str], bytes]:
    """(run name, kind) -> the tar its parts make, refusing a run whose parts are not all here."""
    parts: dict[tuple[str, str], dict[int, Path]] = {}
    totals: dict[tuple[str, str], int] = {}
    for folder in folders:
        for path in folder.iterdir():
            match = PART_NAME.fullmatch(path.name)
            if match:
                key = (match["name"], match["kind"])
                parts.setdefault(key, {})[int(match["index"])] = path
                totals[key] = int(match["total"])
    joined = {}
    for key, pieces in parts.items():
        missing = sorted(set(range(1, totals[key] + 1)) - set(pieces))
        if missing:
            raise SystemExit(f"error: {key[0]} ({key[1]}) lacks parts {missing} of {totals[key]}; give every folder "
                             "its pack calls came back to")
        joined[key] = b"".join(pieces[i].read_bytes() for i in sorted(pieces))
    return joined


def unpack(folders: list[Path], repo: Path, resume_root: Path) -> None:
    """Here: checkpoints into the repository, resume points under the resume root; never over existing files."""
    joined = joined_parts(folders)
    for (name, kind), blob in sorted(joined.items()):
        target = repo if kind == "checkpoint" else resume_root / repo.resolve().relative_to("/")
        with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
            if any((target / member).is_file() for member in tar.getnames()):
                raise SystemExit(f"error: a {kind} of {name} already exists under {target}; "
                                 "move it away first (unpacking would overwrite it)")
            tar.extractall(target, filter="data")
        print(f"{kind} {name} -> {target}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    start = sub.add_parser("launch")
    start.add_argument("work", type=Path)
    start.add_argument("runs", nargs="*", help="ENV METHOD SEED triples (main-matrix runs)")
    start.add_argument("--queue", type=Path, help="a queue file: its unmarked paper_lib.agents.training lines")
    start.add_argument("--device", default="cuda", help="torch device (cpu for a dry run here)")
    start.add_argument("--timesteps", type=int, default=None, help="training steps (default: the env's budget)")
    look = sub.add_parser("watch")
    look.add_argument("work", type=Path)
    look.add_argument("--until", type=float, required=True, help="seconds to watch")
    look.add_argument("--stop", action="store_true", help="then kill the runs still training, ready to pack")
    send = sub.add_parser("pack")
    send.add_argument("work", type=Path)
    send.add_argument("--out", type=Path, required=True)
    back = sub.add_parser("unpack")
    back.add_argument("folders", type=Path, nargs="+", help="folders the lent machine's files came back to")
    back.add_argument("--resume-root", type=Path, required=True, help="PAPER_LIB_RESUME_ROOT of the training queue")
    args = parser.parse_args(argv)
    repo = Path(__file__).resolve().parent.parent
    if args.command == "launch":
        if len(args.runs) % 3 or not (args.runs or args.queue):
            parser.error("give runs as ENV METHOD SEED triples, or --queue FILE")
        try:
            runs = [main_matrix_run(args.runs[i], args.runs[i + 1], int(args.runs[i + 2]))
                    for i in range(0, len(args.runs), 3)]
            runs += read_queue(args.queue) if args.queue else []
        except ValueError as err:
            parser.error(f"{err} (runs are ENV METHOD SEED triples with an integer seed)"
                         if "invalid literal" in str(err) else str(err))
        except OSError as err:
            parser.error(f"cannot read the queue file: {err}")
        launch(args.work, runs, repo, args.device, args.timesteps)
    elif args.command in ("watch", "pack") and not state_file(args.work).is_file():
        parser.error(f"{args.work} holds no launched runs ({state_file(args.work).name} is missing); "
                     "give the WORK folder of `launch`")
    elif args.command == "watch":
        watch(args.work, args.until, args.stop)
    elif args.command == "pack":
        pack(args.work, args.out)
    else:
        absent = [str(f) for f in args.folders if not f.is_dir()]
        if absent:
            parser.error(f"not a folder: {', '.join(absent)}; give the folders the pack calls' files came back to")
        unpack(args.folders, repo, args.resume_root)


if __name__ == "__main__":
    main()
