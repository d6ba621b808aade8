"""Train several matrix runs at once on a lent GPU machine, within its short lease, and bring them back.

A lent machine (16 cores, one GPU) is held for minutes, and one call returns at most 8 files of 16 MiB
(64 MiB in all). So, on the machine:

    python scripts/gpu_runs.py launch WORK ENV METHOD SEED [ENV METHOD SEED ...]   # returns at once
    python scripts/gpu_runs.py watch WORK --until 540 --stop     # progress every 30 s, then stop the runs
    python scripts/gpu_runs.py pack WORK --out $OUT               # again, in quick calls, until none is left

`launch` starts each run as `python -m paper_lib.train ... --device cuda --env-processes` in its own
process session, so it outlives the call. `pack` sends what the runs reached: a finished run as its
checkpoint folder (`ENV_METHOD_seedN.tar.gz`, ~4 MB), an unfinished one as its resume point (~20 MB
with Adam's moments, in 15 MiB parts `ENV_METHOD_seedN.resume.tar.partNN`), as many as one call returns.
Here, `unpack` puts them in place: checkpoints into the repository, resume points under the resume
root, where `scripts/train_queue.sh` continues them on this machine's CPUs (config.json's `segments`
then says which steps ran where).

The runs import a copy of paper_lib and params.yaml (WORK/code): a later call replaces the working tree.
Measured on leases (Atari, 8 envs a run): H100, 2026-11-24, envs stepped in the run's own process:
14 runs at once ~370 steps/s each, 5 at once ~520. H200, 2026-11-26, `--env-processes`: 8 runs at once
~850 steps/s each (MC Dropout ~650), 4 at once the same (the bound is each run's own loop, not the
cores), the first resume point after ~90 s of start-up. A 1e6-step Atari run needs ~20 min: more than
one call (10 min), so runs come back as resume points and finish here.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

PROFILE_DIR = Path("results/paper/checkpoints")
CHECK_EVERY = 30
RESUME_EVERY = 25_000  # finer progress readings than the default 50k
MAX_FILES, MAX_BYTES = 8, 60 * 2**20  # what one call of the lent machine returns (64 MiB), with room
PART_BYTES = 15 * 2**20


def state_file(work: Path) -> Path:
    return work / "runs.json"


def load_state(work: Path) -> dict:
    return json.loads(state_file(work).read_text())


def save_state(work: Path, state: dict) -> None:
    state_file(work).write_text(json.dumps(state, indent=1))


def checkpoint_dir(run: dict) -> Path:
    return PROFILE_DIR / run["env"] / run["method"] / f"seed{run['seed']}"


def run_name(run: dict) -> str:
    return f"{run['env']}_{run['method']}_seed{run['seed']}"


def resume_point(work: Path, run: dict) -> Path:
    """Where paper_lib.train keeps the run's resume point (PAPER_LIB_RESUME_ROOT=WORK/resume)."""
    return work / "resume" / (work / checkpoint_dir(run)).relative_to("/")


def launch(work: Path, runs: list[tuple[str, str, int]], repo: Path, device: str = "cuda",
           timesteps: int | None = None, resume_every: int = RESUME_EVERY) -> None:
    """Start every run in its own session and record its pid (beside the runs of an earlier launch)."""
    work = work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    code = work / "code"
    if not code.exists():  # later calls replace the working tree under the running runs
        shutil.copytree(repo / "paper_lib", code / "paper_lib", ignore=shutil.ignore_patterns("__pycache__"))
        shutil.copy2(repo / "params.yaml", code / "params.yaml")
    env = {**os.environ, "PAPER_LIB_RESUME_ROOT": str(work / "resume"), "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(filter(None, [str(code), os.environ.get("PYTHONPATH")]))}
    state = load_state(work) if state_file(work).is_file() else {"launched": time.time(), "runs": []}
    for env_id, method, seed in runs:
        run = {"env": env_id, "method": method, "seed": seed, "status": "running"}
        cmd = [sys.executable, "-m", "paper_lib.train", env_id, method, str(seed), str(work / checkpoint_dir(run)),
               "--device", device, "--env-processes", "--resume-every", str(resume_every)]
        if timesteps is not None:
            cmd += ["--timesteps", str(timesteps)]
        log = open(work / f"{run_name(run)}.log", "w")
        proc = subprocess.Popen(cmd, cwd=code, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        run["pid"] = proc.pid
        state["runs"].append(run)
        print(f"started {env_id} {method} seed {seed} (pid {proc.pid})", flush=True)
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
    """Pack the next runs not yet sent, as many as one call returns; print what is left."""
    work = work.resolve()
    state = load_state(work)
    out.mkdir(parents=True, exist_ok=True)
    files, size = 0, 0
    for run in state["runs"]:
        if run.get("packed") or run["status"] == "running":
            continue
        finished = run["status"] == "finished"
        folder = work / checkpoint_dir(run) if finished else resume_point(work, run)
        if not (folder / ("config.json" if finished else "state.pkl")).is_file():
            run["packed"] = "nothing"  # stopped before its first resume point
            continue
        need = sum(f.stat().st_size for f in folder.iterdir())
        parts = 1 if finished else -(-need // PART_BYTES)
        if files + parts > max_files or size + need > max_bytes:
            break
        if finished:
            with tarfile.open(out / f"{run_name(run)}.tar.gz", "w:gz") as tar:
                tar.add(folder, arcname=str(checkpoint_dir(run)))
        else:
            data = io.BytesIO()
            with tarfile.open(fileobj=data, mode="w") as tar:
                tar.add(folder, arcname=str(checkpoint_dir(run)))
            blob = data.getvalue()
            for i in range(0, len(blob), PART_BYTES):
                (out / f"{run_name(run)}.resume.tar.part{i // PART_BYTES:02d}").write_bytes(blob[i:i + PART_BYTES])
        files, size = files + parts, size + need
        run["packed"] = True
        what = "checkpoint" if finished else f"resume point at step {progress(work, run)}"
        print(f"packed {run_name(run)}: {what}", flush=True)
    save_state(work, state)
    left = [run_name(r) for r in state["runs"] if not r.get("packed")]
    print(f"left to pack: {left or 'none'}", flush=True)


def unpack(folders: list[Path], repo: Path, resume_root: Path) -> None:
    """Here: checkpoints into the repository, resume points (parts joined) under the resume root."""
    parts: dict[str, list[Path]] = {}
    for folder in folders:
        for path in sorted(folder.iterdir()):
            if path.name.endswith(".tar.gz"):
                with tarfile.open(path) as tar:
                    tar.extractall(repo, filter="data")
                print(f"checkpoint {path.name} -> {repo}")
            elif ".resume.tar.part" in path.name:
                parts.setdefault(path.name.split(".resume.tar.part")[0], []).append(path)
    target = resume_root / repo.resolve().relative_to("/")
    for name, pieces in parts.items():
        blob = b"".join(p.read_bytes() for p in sorted(pieces, key=lambda p: p.name))
        with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
            if any((target / member).is_file() for member in tar.getnames()):
                raise SystemExit(f"error: a resume point of {name} already exists under {target}; "
                                 "move it away first (unpacking would overwrite it)")
            tar.extractall(target, filter="data")
        print(f"resume point {name} -> {target}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    start = sub.add_parser("launch")
    start.add_argument("work", type=Path)
    start.add_argument("runs", nargs="+", help="ENV METHOD SEED triples")
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
        if len(args.runs) % 3:
            parser.error("give runs as ENV METHOD SEED triples")
        triples = [(args.runs[i], args.runs[i + 1], int(args.runs[i + 2])) for i in range(0, len(args.runs), 3)]
        launch(args.work, triples, repo, args.device, args.timesteps)
    elif args.command == "watch":
        watch(args.work, args.until, args.stop)
    elif args.command == "pack":
        pack(args.work, args.out)
    else:
        unpack(args.folders, repo, args.resume_root)


if __name__ == "__main__":
    main()
