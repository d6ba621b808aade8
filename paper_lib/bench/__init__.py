"""What uncertainty costs: every method side by side with plain SB3 PPO, same network sizes.

    python -m paper_lib.bench                  # HalfCheetah-v5 + Seaquest, ~10 min on 2 cores
    python -m paper_lib.bench --quick          # ~1 min: shorter rollouts, 256 states, no memory
    python -m paper_lib.bench --envs HalfCheetah-v5 --methods baseline masksembles --out results/bench

Measured in one run, per env and method (plain SB3 PPO is the method "baseline"):
- train_steps_per_s: PPO training throughput at the paper's settings (after one warm-up
  iteration), split into rollout_s_per_iter and update_s_per_iter; plus env_steps_per_s of
  the same vectorized env under random actions, the ceiling (method "env_only").
- predict_b1, predict_bN: model.predict (deterministic) on 1 and on N states.
- act_uncertainty_b1: predict plus every uncertainty measure for one state, divided by the
  baseline's predict_b1; uncertainty_bN: every measure for N states, divided by its predict_bN;
  compiled_act_uncertainty_b1: act_uncertainty_b1 on the compiled policy (`paper_lib.deploy.compile_policy`,
  Masksembles and Ensemble MLPs only).
- peak_rss_{train,infer}_mb and rss_increase_*: peak memory of a fresh process (see memory.py).
- every inference timing's limit: the multiply-adds it needs (arithmetic.py) as a plain dense
  computation timed in the same run (limits.py); bench.csv's limit and time_over_limit.
Ratios are cost ratios (>1 = costs more than plain SB3 PPO); targets are in report.TARGETS.
Outputs: <out>/bench.csv (one row per env x method x measurement), <out>/bench.md, and
<out>/bench_timings.csv (every repetition of every timing: the speed claim's input).
"""

from paper_lib.bench.config import BenchConfig, quick_config
from paper_lib.bench.models import build_model
from paper_lib.bench.report import TARGETS, Row
from paper_lib.bench.run import run_benchmark

__all__ = ["TARGETS", "BenchConfig", "Row", "build_model", "quick_config", "run_benchmark"]
