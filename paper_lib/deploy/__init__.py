"""Trained policies in the form an agent's control loop runs them: one state at a time, with its uncertainty.

`compile_policy(policy)` copies a Masksembles or Ensemble MLP policy's weights and runs them compiled (numba); its
`act_with_uncertainty(obs)` gives the same actions and measures as `paper_lib.measures.act_with_uncertainty` (up to
float rounding) at a fraction of torch's per-call cost on one state (docs/benchmarks.md).
"""

from paper_lib.deploy.compiled_policy import CompiledMemberPolicy, NotCompilable, compile_policy

__all__ = ["CompiledMemberPolicy", "NotCompilable", "compile_policy"]
