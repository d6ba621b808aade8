"""Train several matrix runs at once on a lent GPU machine, inside its short lease, and send back the finished ones.

A lent machine (16 cores, one GPU) is held for minutes, not hours, and returns at most 8 files. So:

    python scripts/gpu_runs.py launch WORK --deadline 700 ENV METHOD SEED [ENV METHOD SEED ...]
    python scripts/gpu_runs.py watch WORK --until 560 --deadline 700 --out $OUT   # again in a later call

`launch` starts each run as `python -m paper_lib.train ... --device cuda --env-processes` in its own
process session (so it outlives the call that started it) and returns. `watch` reports progress every
30 s; where the runs cannot all finish by `--deadline` (seconds after launch, from the rate of the last
minute), it kills the last-listed unfinished run, so the others get its cores. When every run has
ended, or after `--until` seconds, it packs each newly finished checkpoint folder as
`ENV_METHOD_seedN.tar.gz` under `--out` (paths as in the repository: unpack in its root, then
`scripts/land_run.sh`). Killed or unfinished runs are lost: their resume points are too large to return.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

PROFILE_DIR = Path("results/paper/checkpoints")
CHECK_EVERY = 30
RATE_WINDOW = 60
FIRST_TRIAGE = 150
RESUME_EVERY = 25_000  # finer progress readings than the default 50k


def state_file(work: Path) -> Path:
    return work / "runs.json"


def load_state(work: Path) -> dict:
    return json.loads(state_file(work).read_text())


def save_state(work: Path, state: dict) -> None:
    state_file(work).write_text(json.dumps(state, indent=1))


def checkpoint_dir(run: dict) -> Path:
    return PROFILE_DIR / run["env"] / run["method"] / f"seed{run['seed']}"


def launch(work: Path, runs: list[tuple[str, str, int]], repo: Path, device: str = "cuda",
           timesteps: int | None = None) -> None:
    """Start every run in its own session and record its pid and output folder."""
    work = work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PAPER_LIB_RESUME_ROOT": str(work / "resume"), "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join(filter(None, [str(repo), os.environ.get("PYTHONPATH")]))}
    started = time.time()
    state = {"launched": started, "runs": []}
    for env_id, method, seed in runs:
        run = {"env": env_id, "method": method, "seed": seed, "status": "running"}
        out = work / checkpoint_dir(run)
        cmd = [sys.executable, "-m", "paper_lib.train", env_id, method, str(seed), str(out),
               "--device", device, "--env-processes", "--resume-every", str(RESUME_EVERY)]
        if timesteps is not None:
            cmd += ["--timesteps", str(timesteps)]
        log = open(work / f"{env_id}_{method}_seed{seed}.log", "w")
        proc = subprocess.Popen(cmd, cwd=repo, env=env, stdout=log, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
        run.update(pid=proc.pid, history=[])
        state["runs"].append(run)
        print(f"started {env_id} {method} seed {seed} (pid {proc.pid})", flush=True)
    save_state(work, state)


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except FileNotFoundError:
        return False


def progress(work: Path, run: dict) -> tuple[float, int] | None:
    """(when, step count) of the run's last resume point, written every RESUME_EVERY steps."""
    path = work / "resume" / (work / checkpoint_dir(run)).relative_to("/") / "state.pkl"
    try:
        when = path.stat().st_mtime
        with open(path, "rb") as f:
            return when, int(pickle.load(f)["num_timesteps"])
    except (OSError, EOFError, pickle.UnpicklingError, KeyError):
        return None


def refresh(work: Path, state: dict) -> None:
    """Mark finished and crashed runs and append (time, steps) to each running run's history."""
    for run in state["runs"]:
        if run["status"] != "running":
            continue
        if (work / checkpoint_dir(run) / "config.json").is_file():
            run["status"] = "finished"
        elif not alive(run["pid"]):
            run["status"] = "crashed"
        else:
            reading = progress(work, run)
            if reading and (not run["history"] or reading[1] > run["history"][-1][1]):
                run["history"].append(reading)


def recent_rate(run: dict, now: float) -> float | None:
    """Steps per second over the last minute, from the resume points' step counts."""
    history = run["history"]
    old = [h for h in history if now - h[0] >= RATE_WINDOW]
    if not old or history[-1][1] <= old[-1][1]:
        return None
    return (history[-1][1] - old[-1][1]) / (history[-1][0] - old[-1][0])


def triage(state: dict, now: float, deadline: float, budget: int) -> None:
    """Kill the last-listed running run while some running run is projected to miss the deadline."""
    if now - state["launched"] < FIRST_TRIAGE or now - state.get("last_kill", 0) < RATE_WINDOW + CHECK_EVERY:
        return
    running = [r for r in state["runs"] if r["status"] == "running"]
    late = []
    for run in running:
        rate = recent_rate(run, now)
        if rate:
            when, steps = run["history"][-1]
            finish = when + (budget - steps) / rate - state["launched"]
            late.append(finish > deadline)
    if len(running) > 1 and any(late):
        victim = running[-1]
        os.killpg(victim["pid"], signal.SIGKILL)
        victim["status"] = "killed"
        state["last_kill"] = now
        for run in running[:-1]:
            run["history"] = run["history"][-1:]
        print(f"killed {victim['env']} {victim['method']}: not all runs would finish by {deadline:.0f} s", flush=True)


def pack(work: Path, state: dict, out: Path) -> None:
    for run in state["runs"]:
        if run["status"] == "finished" and not run.get("packed"):
            name = out / f"{run['env']}_{run['method']}_seed{run['seed']}.tar.gz"
            with tarfile.open(name, "w:gz") as tar:
                tar.add(work / checkpoint_dir(run), arcname=str(checkpoint_dir(run)))
            config = json.loads((work / checkpoint_dir(run) / "config.json").read_text())
            run["packed"] = True
            print(f"packed {name.name} ({name.stat().st_size / 1e6:.1f} MB, trained in {config['wall_seconds']:.0f} s"
                  f" on {config['gpu']})", flush=True)


def watch(work: Path, until: float, deadline: float | None, out: Path, budget: int) -> None:
    work = work.resolve()
    state = load_state(work)
    start = time.time()
    while True:
        now = time.time()
        refresh(work, state)
        line = ", ".join(f"{r['env'][:8]} {r['method']} {r['history'][-1][1] if r['history'] else 0}"
                         if r["status"] == "running" else f"{r['env'][:8]} {r['method']} {r['status']}"
                         for r in state["runs"])
        print(f"[{now - state['launched']:.0f} s] {line}", flush=True)
        if deadline is not None:
            triage(state, now, deadline, budget)
        save_state(work, state)
        if all(r["status"] != "running" for r in state["runs"]) or now - start + CHECK_EVERY > until:
            break
        time.sleep(CHECK_EVERY)
    out.mkdir(parents=True, exist_ok=True)
    pack(work, state, out)
    save_state(work, state)
    for run in state["runs"]:
        if run["status"] == "crashed":
            log = work / f"{run['env']}_{run['method']}_seed{run['seed']}.log"
            print(f"--- {log.name} (crashed)\n" + log.read_text()[-2000:], flush=True)


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
    look.add_argument("--until", type=float, required=True, help="seconds to watch before packing")
    look.add_argument("--deadline", type=float, default=None, help="seconds after launch every run must end by")
    look.add_argument("--out", type=Path, required=True)
    look.add_argument("--budget", type=int, default=1_000_000, help="training steps of every run")
    args = parser.parse_args(argv)
    if args.command == "launch":
        if len(args.runs) % 3:
            parser.error("give runs as ENV METHOD SEED triples")
        triples = [(args.runs[i], args.runs[i + 1], int(args.runs[i + 2])) for i in range(0, len(args.runs), 3)]
        launch(args.work, triples, Path(__file__).resolve().parent.parent, args.device, args.timesteps)
    else:
        watch(args.work, args.until, args.deadline, args.out, args.budget)


if __name__ == "__main__":
    main()
