"""PEDM: a probabilistic ensemble dynamics model as an OOD detector (Haider et al., AAMAS 2023).

A transition (s, a, s') is OOD when the model trained on ID transitions finds s' surprising given
(s, a). Everything below follows the authors' code (github.com/FraunhoferIKS/pedm-ood, commit fbef8bb),
file and line cited where a choice is made:

- **Data.** States and actions are standardized with the training episodes' mean and std
  (``ood_baselines/common/base_detector.py`` l. 62-80, ``utils/data.py`` l. 20-27, ``np.std``: ddof 0);
  the network's inputs ``[s, a]`` are standardized a second time inside the model
  (``pedm/nn_models/prob_ensemble.py`` l. 99-104, 107-108: ``torch.std``, ddof 1, std < 1e-12 -> 1);
  the target is the standardized delta ``s' - s`` (``pedm/nn_models/default_cfg.py`` l. 18-19).
  10% of the episodes are held out (``utils/data.py`` l. 39-45: ``int(n * 0.9)`` train episodes).
- **Model** (``default_cfg.py`` l. 111-119, MJHalfCheetah-v0): 5 members, 4 hidden layers of 200 SiLU
  ("swish") units, per-layer L2 decays 2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4 (``prob_ensemble.py`` l. 93-97:
  ``decay * sum(w**2) / 2``), weights from a normal truncated at 2 std with std ``1 / (2 sqrt(fan_in))``,
  biases 0 (l. 19-28). Each member outputs a mean and a log-variance, the latter bounded softly by
  learnable ``max_logvar`` (init 0.5) and ``min_logvar`` (init -10) (l. 82-83, 112-113).
- **Training** (``prob_ensemble.py`` l. 131-186, ``pedm_detector.py`` l. 153-167): Adam, lr 1e-3, batch 512,
  2000 epochs; each member trains on its own bootstrap resample of the training transitions, re-shuffled
  (row by row) every epoch; the loss per member is the mean of ``(mu - y)^2 / var + log var`` over batch
  and dimensions, summed over members, plus ``0.01 * (sum max_logvar - sum min_logvar)`` and the decays.
  After each epoch the validation MSE of the members' means (on a bootstrap resample of the held-out
  transitions, l. 188-200) decides whether the weights are the best so far; the best are kept
  (``utils/callbacks.py`` l. 64-67, 92-94; patience 1e6: no early stop).
- **Score** (``pedm_detector.py`` l. 38-41 defaults ``criterion="pred_error_samples"``, ``n_part=1000``,
  ``aggregation_function="min_mean"``; l. 79-82, 134-135; ``utils/stats.py`` l. 83): 1000 particles, 200
  per member (``prob_ensemble.py`` l. 207-213), each a sample ``s + mu_m + sqrt(var_m) * eps`` of s'; the
  score is the **minimum over particles of the mean over state dimensions of the squared error** to the
  observed s' (standardized). It is neither the Gaussian NLL of the ensemble mean nor a per-member NLL
  (that is the non-default ``pred_error_pdf`` criterion, l. 89-98).

Our one change to make scores reproducible and batch-invariant (docs/deviations.md): the particles'
standard-normal draws ``eps`` are drawn once at fit (seeded) and shared by every transition (common
random numbers), so a transition's score is a fixed function of the transition, whatever batch it is
scored in; its distribution over seeds is PEDM's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.stats import truncnorm
from torch import nn
from torch.nn import functional as F


@dataclass(frozen=True)
class PEDMConfig:
    """PEDM's sizes and training (MJHalfCheetah-v0 in ``default_cfg.py``; the other MuJoCo entries differ in depth only)."""

    ens_size: int = 5
    hidden: tuple[int, ...] = (200, 200, 200, 200)
    decays: tuple[float, ...] = (2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4)
    lr: float = 1e-3
    epochs: int = 2000
    batch_size: int = 512
    holdout_fraction: float = 0.1
    n_particles: int = 1000

    def __post_init__(self) -> None:
        if len(self.decays) != len(self.hidden) + 1:
            raise ValueError(f"decays needs one entry per layer ({len(self.hidden) + 1}), got {len(self.decays)}.")
        for name in ("ens_size", "epochs", "batch_size", "n_particles"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"PEDMConfig.{name} must be a positive integer, got {value!r}.")
        if self.n_particles % self.ens_size:
            raise ValueError(f"n_particles ({self.n_particles}) must be a multiple of ens_size ({self.ens_size}): "
                             "PEDM gives each member the same number of particles.")
        if not 0.0 <= self.holdout_fraction < 1.0:
            raise ValueError(f"holdout_fraction must lie in [0, 1), got {self.holdout_fraction!r}.")


class ProbEnsemble(nn.Module):
    """``ens_size`` MLPs in one batched tensor; each outputs a Gaussian over the standardized delta s' - s."""

    def __init__(self, n_in: int, n_out: int, config: PEDMConfig, rng: np.random.Generator) -> None:
        super().__init__()
        sizes = (n_in, *config.hidden, 2 * n_out)
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for f_in, f_out in zip(sizes[:-1], sizes[1:]):
            w = truncnorm.rvs(-2, 2, scale=1.0 / (2.0 * np.sqrt(f_in)), size=(config.ens_size, f_in, f_out),
                              random_state=rng)
            self.weights.append(nn.Parameter(torch.tensor(w, dtype=torch.float32)))
            self.biases.append(nn.Parameter(torch.zeros(config.ens_size, 1, f_out)))
        self.max_logvar = nn.Parameter(torch.full((1, n_out), 0.5))
        self.min_logvar = nn.Parameter(torch.full((1, n_out), -10.0))
        self.register_buffer("in_mu", torch.zeros(1, n_in))
        self.register_buffer("in_sigma", torch.ones(1, n_in))
        self.n_out = n_out
        self.decays = config.decays

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(members, n, n_in) -> mean and bounded log-variance, each (members, n, n_out)."""
        h = (x - self.in_mu) / self.in_sigma
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h.matmul(w) + b
            if i < last:
                h = F.silu(h)
        mean, logvar = h[..., :self.n_out], h[..., self.n_out:]
        logvar = self.max_logvar - F.softplus(self.max_logvar - logvar)
        logvar = self.min_logvar + F.softplus(logvar - self.min_logvar)
        return mean, logvar

    def decay_loss(self) -> torch.Tensor:
        return sum(d * (w ** 2).sum() / 2.0 for d, w in zip(self.decays, self.weights))


def pedm_score(mean: np.ndarray, var: np.ndarray, target: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """PEDM's ``pred_error_samples`` + ``min_mean`` score from member Gaussians (numpy, the definition).

    mean, var: (members, n, d); target: (n, d), the observed standardized delta s' - s;
    eps: (members, particles_per_member, d) standard-normal draws. Returns (n,).
    """
    samples = mean[:, :, None, :] + np.sqrt(var)[:, :, None, :] * eps[:, None, :, :]  # (m, n, p, d)
    err = ((samples - target[None, :, None, :]) ** 2).mean(axis=-1)  # mean over state dims
    return err.min(axis=(0, 2))  # min over every particle of every member


def _finite(name: str, arr: np.ndarray, ndim: int) -> np.ndarray:
    out = np.asarray(arr, dtype=float)
    if out.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-D array, got shape {out.shape}.")
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{name} contains NaN/inf values; drop those transitions first.")
    return out


def check_transitions(obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, d_s), (n, d_a), (n, d_s) finite float arrays with one row per transition, or a ValueError."""
    s, a, s2 = _finite("obs", obs, 2), _finite("actions", actions, 2), _finite("next_obs", next_obs, 2)
    if not (len(s) == len(a) == len(s2)):
        raise ValueError(f"obs, actions and next_obs need one row per transition, got {len(s)}, {len(a)}, {len(s2)}.")
    if s.shape != s2.shape:
        raise ValueError(f"obs {s.shape} and next_obs {s2.shape} must have the same shape.")
    return s, a, s2


def _std(x: np.ndarray) -> np.ndarray:
    sd = x.std(axis=0)
    return np.where(sd < 1e-12, 1.0, sd)  # PEDM divides by 0 on a constant dimension; we do not


class PEDMDetector:
    """Fit on ID transitions (``fit``), score any transitions (``score``): higher = more surprising s'."""

    def __init__(self, config: PEDMConfig | None = None, seed: int = 0, device: str = "cpu") -> None:
        self.config = config or PEDMConfig()
        self.seed = int(seed)
        self.device = torch.device(device)  # a GPU's floats differ from the CPU's: record which fit a run
        self.model_: ProbEnsemble | None = None
        self.history_: list[tuple[float, float]] = []

    def _standardize(self, s: np.ndarray, a: np.ndarray, s2: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        zs, zs2 = (s - self.obs_mu_) / self.obs_sigma_, (s2 - self.obs_mu_) / self.obs_sigma_
        za = (a - self.act_mu_) / self.act_sigma_
        x = torch.tensor(np.concatenate([zs, za], axis=1), dtype=torch.float32, device=self.device)
        return x, torch.tensor(zs2 - zs, dtype=torch.float32, device=self.device)

    def fit(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray, episodes: np.ndarray) -> "PEDMDetector":
        """Train on ID transitions; ``episodes`` (one id per transition) decides the held-out episodes."""
        cfg = self.config
        s, a, s2 = check_transitions(obs, actions, next_obs)
        ep = np.asarray(episodes)
        if ep.shape != (len(s),):
            raise ValueError(f"episodes must give one id per transition ({len(s)}), got shape {ep.shape}.")
        names = list(dict.fromkeys(ep.tolist()))  # episodes in order of appearance
        rng = np.random.default_rng(self.seed)
        torch.manual_seed(self.seed)
        order = rng.permutation(len(names))
        n_train = int(len(names) * (1 - cfg.holdout_fraction))
        if n_train < 1 or (cfg.holdout_fraction > 0 and n_train == len(names)):
            raise ValueError(f"PEDMDetector.fit got {len(names)} episode(s): holding out {cfg.holdout_fraction:.0%} "
                             "needs at least one episode on each side; pass more ID episodes.")
        train_eps = [names[i] for i in sorted(order[:n_train])]  # a list, not a set: no hash-seed dependent order
        train = np.isin(ep, train_eps)
        if train.sum() < 2:
            raise ValueError(f"PEDMDetector.fit needs at least 2 training transitions, got {int(train.sum())}.")
        # base_detector.py: statistics over the training episodes' states (each episode's s_0..s_T) and actions.
        last = np.array([np.flatnonzero(ep == e)[-1] for e in train_eps])
        states = np.concatenate([s[train], s2[last]])
        self.obs_mu_, self.obs_sigma_ = states.mean(axis=0), _std(states)
        self.act_mu_, self.act_sigma_ = a[train].mean(axis=0), _std(a[train])
        x, y = self._standardize(s, a, s2)
        x_tr, y_tr, x_val, y_val = x[train], y[train], x[~train], y[~train]

        model = ProbEnsemble(x.shape[1], y.shape[1], cfg, rng).to(self.device)
        model.in_mu.copy_(x_tr.mean(0, keepdim=True))
        sigma = x_tr.std(0, keepdim=True)
        model.in_sigma.copy_(torch.where(sigma < 1e-12, torch.ones_like(sigma), sigma))
        optim = torch.optim.Adam(model.parameters(), lr=cfg.lr)
        n = len(x_tr)
        idxs = rng.integers(n, size=(cfg.ens_size, n))  # one bootstrap resample per member
        best, best_state = np.inf, None
        self.history_ = []
        for _ in range(cfg.epochs):
            model.train()
            losses = []
            for start in range(0, n, cfg.batch_size):
                b = torch.from_numpy(idxs[:, start:start + cfg.batch_size]).to(self.device)
                mean, logvar = model(x_tr[b])
                nll = ((mean - y_tr[b]) ** 2) * torch.exp(-logvar) + logvar
                loss = nll.mean(-1).mean(-1).sum() + 0.01 * (model.max_logvar.sum() - model.min_logvar.sum())
                loss = loss + model.decay_loss()
                optim.zero_grad()
                loss.backward()
                optim.step()
                losses.append(loss.item())
            val = self._val_mse(model, x_val, y_val, rng) if len(x_val) else np.nan
            self.history_.append((float(np.mean(losses)), val))
            if not len(x_val) or val < best:
                best, best_state = val, {k: v.detach().clone() for k, v in model.state_dict().items()}
            idxs = np.take_along_axis(idxs, np.argsort(rng.uniform(size=idxs.shape), axis=-1), axis=-1)
        model.load_state_dict(best_state)
        model.eval()
        self.model_ = model
        per_member = cfg.n_particles // cfg.ens_size
        self.eps_ = rng.standard_normal((cfg.ens_size, per_member, y.shape[1])).astype(np.float32)
        return self

    def _val_mse(self, model: ProbEnsemble, x_val: torch.Tensor, y_val: torch.Tensor, rng: np.random.Generator) -> float:
        model.eval()
        with torch.no_grad():
            b = torch.from_numpy(rng.integers(len(x_val), size=(self.config.ens_size, len(x_val)))).to(self.device)
            mean, _ = model(x_val[b])
            return float(((mean - y_val[b]) ** 2).mean(-1).mean(-1).mean())

    @torch.no_grad()
    def member_gaussians(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each member's mean and variance of the standardized delta, (members, n, d), and the observed delta (n, d)."""
        if self.model_ is None:
            raise ValueError("PEDMDetector.score called before fit; call fit(ID transitions) first.")
        s, a, s2 = check_transitions(obs, actions, next_obs)
        if s.shape[1] != len(self.obs_mu_) or a.shape[1] != len(self.act_mu_):
            raise ValueError(f"transitions have {s.shape[1]} state / {a.shape[1]} action dims but the model was fit on "
                             f"{len(self.obs_mu_)} / {len(self.act_mu_)}; score transitions of the same env.")
        x, y = self._standardize(s, a, s2)
        mean, logvar = self.model_(x.expand(self.config.ens_size, -1, -1))
        return mean.cpu().numpy(), torch.exp(logvar).cpu().numpy(), y.cpu().numpy()

    def score(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray, chunk: int = 256) -> np.ndarray:
        """One score per transition (PEDM's min-over-particles squared error), in chunks to bound memory."""
        s, a, s2 = check_transitions(obs, actions, next_obs)
        out = []
        for i in range(0, len(s), chunk):
            mean, var, target = self.member_gaussians(s[i:i + chunk], a[i:i + chunk], s2[i:i + chunk])
            out.append(pedm_score(mean, var, target, self.eps_))
        return np.concatenate(out) if out else np.zeros(0)
