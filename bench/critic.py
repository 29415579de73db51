"""Calibration of the local VHGP critic at ERSAC's sample sizes (prints figures; not a test).

    .venv/bin/python bench/critic.py                 # full (30 replicates per cell, ~5 min)
    .venv/bin/python bench/critic.py --quick         # 6 replicates, 2 sizes (< 1 min)
    .venv/bin/python bench/critic.py --variants paper-bounds,default   # compare critic choices

Problems with a known mean J(x) and noise std r(x): Goldberg, Williams, Yuan (1-D, the VHGP
paper's sets), the bracing-shaped 1-D problem of bench/learner.py with the paper's bracing
ball, the RAHBO sine (s = 1) and the heteroscedastic Branin (s = 1) (2-D, risk-averse BO
benchmarks), a 7-D problem on the lifting task's parameter box with the paper's lifting
ball (sigma 0.075, epsilon 3.5 sigma), and lifting-drop: the same box and ball with the
lifting task's two cost modes (a lift costs ~5 or, bottle dropped, ~40; the drop
probability turns from 0 to 1 across about two ball radii).

One replicate: a centre c (uniform inside the box, 2 sigma from its faces), n local points
x_i = clip(c + 1.5 sigma N(0, I)) (an ERSAC run near c: policy drift plus perturbation), their
noisy costs, the critic's neighbourhood of c (the epsilon ball, `LocalCritic`), a cold VHGP
fit.  Then, against the truth:
- |log(r~/r)|: mean over 100 fresh points x ~ c + sigma N(0, I) (where ERSAC evaluates r~);
- slope ratio (grad r~(c) . grad r(c)) / |grad r(c)|^2 (1 = right slope), only where the
  noise changes by >= 10 % across the ball (|grad r| epsilon >= 0.1 r(c));
- coverage of J~(x) +/- 2 r~(x) on fresh noisy samples at those points (Gaussian: 95.4 %);
- NLPD of the fresh samples, VHGP (exact predictive density) minus a homoscedastic GP fitted
  to the same points (negative: the VHGP is better).
Also the published comparison: a plain VHGP on the whole data set (n = 60 / 200 / 200), mean
|log(sigma_hat / sigma)| on a 101-point grid, against the authors' code (Goldberg 0.326,
Williams 0.128, Yuan 0.073; one data set each).

BLAS is pinned to one thread (threadpoolctl) in every process; replicates run in 2 worker
processes.  A PNG of the table is written (--png).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from ersac_hil.critic import GP, VHGP, CriticConfig, CriticError, LocalCritic  # noqa: E402
from ersac_hil.critic._blas import blas_description  # noqa: E402
from ersac_hil.critic.datasets import ALL as DATASETS  # noqa: E402
from ersac_hil.critic.datasets import branin, branin_std, rahbo_sine_cost, rahbo_sine_std  # noqa: E402
from ersac_hil.critic.datasets import jump_cost_mean, jump_cost_sample, jump_cost_std  # noqa: E402
from ersac_hil.learner import Observations  # noqa: E402

Fn = Callable[[np.ndarray], np.ndarray]  # (m, d) -> (m,)
PUBLISHED = {"goldberg": 0.326, "williams": 0.128, "yuan": 0.073}
SIZES = (10, 20, 30, 45, 60)


# ----------------------------------------------------------------------------- problems
@dataclass(frozen=True)
class CalProblem:
    """A heteroscedastic problem on the box [lo, hi] (d,) with ERSAC's sigma and epsilon."""

    name: str
    lo: np.ndarray
    hi: np.ndarray
    J: Fn
    r: Fn
    sigma: float
    epsilon: float
    # noisy costs at X (m, d) -> (m,) (default J + r N(0, 1)); centres drawn from this range
    # (default: the box less 2 sigma on each side)
    sample: Callable[[np.ndarray, np.random.Generator], np.ndarray] | None = None
    centres: tuple[float, float] | None = None

    @property
    def d(self) -> int:
        return self.lo.size

    def draw(self, X: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy costs at X (m, d), (m,)."""
        if self.sample is not None:
            return self.sample(X, rng)
        return self.J(X) + self.r(X) * rng.standard_normal(len(X))

    def grad_r(self, x: np.ndarray) -> np.ndarray:
        """Central differences of r at x (d,) -> (d,)."""
        h = 1e-6 * (self.hi - self.lo)
        E = np.diag(h)
        return (self.r(x[None] + E) - self.r(x[None] - E)) / (2 * h)


def _ds(name: str) -> tuple[Fn, Fn]:
    s = DATASETS[name](np.random.default_rng(0), n=3)
    return (lambda X: s.mean(X[:, 0])), (lambda X: s.std(X[:, 0]))


_LIFT_LO = np.array([-1.0, 0.0, -1.0, 0.0, 0.2, 0.2, 0.2])
_LIFT_HI = np.array([math.pi, 2.5, math.pi, 2.5, 2.0, 2.0, 2.0])
_LIFT_M = np.array([0.55, 0.45, 0.6, 0.5, 0.5, 0.45, 0.55])  # mean's minimum (unit box)
_LIFT_A = np.array([2.0, 1.0, 1.5, 1.0, 1.5, 2.0, 1.0])
_LIFT_W = np.array([0.0, 0.0, 0.5, 0.0, -0.5, -0.5, -0.5])  # faster, higher -> noisier


def _unit(X: np.ndarray) -> np.ndarray:
    return (X - _LIFT_LO) / (_LIFT_HI - _LIFT_LO)


# the lifting task's two modes: a lift succeeds (cost ~5) or drops the bottle (~40), with a
# probability that turns from 0 to 1 across about two epsilon balls (logistic in a direction
# of the unit box); the mean and std follow from the Bernoulli mixture
_DROP_W = np.array([0.5, -0.5, 0.0, 0.5, 0.0, -0.5, 0.0])
_DROP_GAP, _DROP_BASE, _DROP_SCALE = 35.0, 0.3, 0.05


def _drop_p(X: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-((_unit(X) - 0.5) @ _DROP_W) / _DROP_SCALE))


def _drop_sample(X: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    base = 5.0 + _DROP_BASE * rng.standard_normal(len(X))
    return base + _DROP_GAP * (rng.uniform(size=len(X)) < _drop_p(X))


def _problems() -> dict[str, CalProblem]:
    one = np.array([0.0]), np.array([1.0])
    g, w, y = _ds("goldberg"), _ds("williams"), _ds("yuan")
    return {
        "goldberg": CalProblem("goldberg", *one, *g, sigma=0.05, epsilon=0.2),
        "williams": CalProblem("williams", np.array([0.0]), np.array([math.pi]), *w, sigma=0.05 * math.pi, epsilon=0.2 * math.pi),
        "yuan": CalProblem("yuan", *one, *y, sigma=0.05, epsilon=0.2),
        "bracing": CalProblem(
            "bracing", *one, lambda X: 3.0 - 2.4 * X[:, 0] + 1.5 * X[:, 0] ** 2, lambda X: 0.1 + 1.2 * X[:, 0] ** 2,
            sigma=0.05, epsilon=0.2,
        ),
        "rahbo-sine": CalProblem(
            "rahbo-sine", np.array([0.0]), np.array([2.0]), rahbo_sine_cost, rahbo_sine_std, sigma=0.1, epsilon=0.4,
        ),
        "branin": CalProblem(
            "branin", np.array([-5.0, 0.0]), np.array([10.0, 15.0]), branin, branin_std, sigma=0.75, epsilon=3.0,
        ),
        # bracing-shaped with a Bernoulli jump (bench/learner.py's bracing-jump): damage adds 90 with a
        # probability ramping from 0 at 0.35 to 0.17 at 0.7 and 0.8 at 0.85, base noise std 5;
        # centres where the risk term decides (0.25-0.75)
        "bracing-jump": CalProblem(
            "bracing-jump", *one, jump_cost_mean, jump_cost_std, sigma=0.05, epsilon=0.2, sample=jump_cost_sample,
            centres=(0.25, 0.75),
        ),
        "lifting-7d": CalProblem(
            "lifting-7d", _LIFT_LO, _LIFT_HI, lambda X: 1.0 + (_LIFT_A * (_unit(X) - _LIFT_M) ** 2).sum(1),
            lambda X: 0.15 * np.exp(4.0 * (_unit(X) - 0.5) @ _LIFT_W), sigma=0.075, epsilon=3.5 * 0.075,
        ),
        "lifting-drop": CalProblem(
            "lifting-drop", _LIFT_LO, _LIFT_HI, lambda X: 5.0 + _DROP_GAP * _drop_p(X),
            lambda X: np.sqrt(_DROP_BASE**2 + _DROP_GAP**2 * _drop_p(X) * (1.0 - _drop_p(X))),
            sigma=0.075, epsilon=3.5 * 0.075, sample=_drop_sample,
        ),
    }


PROBLEMS = _problems()


# ----------------------------------------------------------------------------- critic variants
def _variants() -> dict[str, Callable[[CalProblem, int], CriticConfig]]:
    """Named critic configurations (a function of the problem and n).  'default' is the
    shipped CriticConfig; the others are the choices measured against it."""

    def cfg(**kw: object) -> Callable[[CalProblem, int], CriticConfig]:
        return lambda p, n: CriticConfig(epsilon=p.epsilon, min_neighbours=min(10, n), max_neighbours=n, **kw)

    return {
        "default": cfg(),
        "previous": cfg(small_n_prior=False, clip_mean=False),
        "no-clip": cfg(clip_mean=False),
        "vhgp-g": cfg(noise_model="vhgp"),
        "cold8": cfg(cold_iter=8),
        "cold30": cfg(cold_iter=30),
        "loglin-prior3": cfg(noise_slope_prior=3.0),
        "loglin-prior30": cfg(noise_slope_prior=30.0),
        "paper-bounds": cfg(g_variance_min=1e-3, g_lengthscale_max=50.0, lengthscale_min=0.02),
        "gvar4": cfg(g_variance_min=4.0),
        "gvar10": cfg(g_variance_min=10.0),
        "gvar4-ls4": cfg(g_variance_min=4.0, g_lengthscale_max=4.0),
        "gls1": cfg(g_lengthscale_max=1.0),
        "gfix1-2": cfg(g_variance_min=1.0, g_variance_max=1.0, g_lengthscale_min=2.0, g_lengthscale_max=2.0),
        "gfix4-2": cfg(g_variance_min=4.0, g_variance_max=4.0, g_lengthscale_min=2.0, g_lengthscale_max=2.0),
        "gfix4-1": cfg(g_variance_min=4.0, g_variance_max=4.0, g_lengthscale_min=1.0, g_lengthscale_max=1.0),
        "gfix10-2": cfg(g_variance_min=10.0, g_variance_max=10.0, g_lengthscale_min=2.0, g_lengthscale_max=2.0),
    }


VARIANTS = _variants()


# ----------------------------------------------------------------------------- one replicate
@dataclass(frozen=True)
class Row:
    problem: str
    n: int
    variant: str
    seed: int
    log_ratio: float
    slope_ratio: float  # nan where the truth is too flat
    coverage: float
    nlpd_vhgp: float
    nlpd_gp: float
    n_fit: int
    crb: float  # Cramer-Rao std of the slope ratio (oracle; nan where flat)
    failed: str = ""


def local_history(p: CalProblem, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """An ERSAC-like history around a centre: (c (d,), X (N, d)) with exactly n points of X
    inside the epsilon ball of c.  The policy mean wanders around c (AR(1), stationary std
    sigma per coordinate) and each episode executes it plus a sigma perturbation, clipped
    to the box; episodes are generated until n of them fall inside the ball."""
    c = rng.uniform(p.lo + 2 * p.sigma, p.hi - 2 * p.sigma) if p.centres is None else rng.uniform(*p.centres, p.d)
    theta, X, inside = c.copy(), [], 0
    while inside < n:
        theta = c + 0.9 * (theta - c) + math.sqrt(1 - 0.81) * p.sigma * rng.standard_normal(p.d)
        x = np.clip(theta + p.sigma * rng.standard_normal(p.d), p.lo, p.hi)
        X.append(x)
        inside += bool(np.linalg.norm(x - c) <= p.epsilon)
    return c, np.array(X)


def slope_crb(p: CalProblem, c: np.ndarray, X: np.ndarray) -> float:
    """Cramer-Rao std of the slope ratio for an oracle that knows the mean and that log r^2
    is linear in x on the points X (n, d): Fisher information (1/2) sum_i u_i u_i',
    u_i = [1, x_i - c].  Returns nan where the slope is zero."""
    g = 2.0 * p.grad_r(c) / p.r(c[None])[0]  # gradient of the log noise variance
    if g @ g == 0:
        return math.nan
    U = np.column_stack([np.ones(len(X)), X - c])
    try:
        cov = np.linalg.inv(0.5 * U.T @ U)[1:, 1:]
    except np.linalg.LinAlgError:
        return math.inf
    return float(math.sqrt(g @ cov @ g) / (g @ g))


def replicate(pname: str, n: int, variant: str, seed: int) -> Row:
    p = PROBLEMS[pname]
    rng = np.random.default_rng([seed, n, sum(map(ord, pname))])
    c, X = local_history(p, n, rng)
    y = p.draw(X, rng)
    Xf = np.clip(c + p.sigma * rng.standard_normal((100, p.d)), p.lo, p.hi)
    yf = p.draw(Xf, rng)
    observations = Observations(p.d)
    for xi, yi in zip(X, y):
        observations.add(xi, float(yi))
    critic = LocalCritic(observations, VARIANTS[variant](p, n))
    nan = float("nan")
    ball = np.flatnonzero(np.linalg.norm(X - c, axis=1) <= p.epsilon)
    try:
        fit = critic.fit(c)
        gp = GP().fit(X[ball], y[ball])
    except CriticError as exc:
        return Row(pname, n, variant, seed, nan, nan, nan, nan, nan, 0, nan, f"{type(exc).__name__}: {exc}")
    pred = fit.predict(Xf)
    r_hat = pred.noise_std
    est = fit.estimate(c)
    g = p.grad_r(c)
    flat = np.linalg.norm(g) * p.epsilon < 0.1 * p.r(c[None])[0]
    return Row(
        pname, n, variant, seed,
        log_ratio=float(np.mean(np.abs(np.log(r_hat / p.r(Xf))))),
        slope_ratio=nan if flat else float(est.grad_r @ g / (g @ g)),
        coverage=float(np.mean(np.abs(yf - pred.f_mean) <= 2 * r_hat)),
        nlpd_vhgp=float(-np.mean(pred.log_density(yf))),
        nlpd_gp=float(-np.mean(gp.predict(Xf).log_density(yf))),
        n_fit=int(fit.ids.size),
        crb=nan if flat else slope_crb(p, c, X[ball]),
    )


def _job(args: tuple[str, int, str, int]) -> Row:
    with threadpool_limits(1, user_api="blas"):
        return replicate(*args)


def published(name: str, draws: int, **options: float) -> list[float]:
    """Plain VHGP (the authors' recipe, no local guards) on whole data sets."""
    out = []
    with threadpool_limits(1, user_api="blas"):
        for s in range(draws):
            data = DATASETS[name](np.random.default_rng(s))
            m = VHGP(**options).fit(data.X, data.y)
            grid = np.linspace(*data.domain, 101)
            out.append(float(np.mean(np.abs(np.log(m.predict(grid[:, None]).noise_std / data.std(grid))))))
    return out


# ----------------------------------------------------------------------------- report
def _q(v: np.ndarray) -> tuple[float, float, float]:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return (math.nan,) * 3
    q1, m, q3 = np.percentile(v, [25, 50, 75])
    return float(m), float(q1), float(q3)


def summarise(rows: list[Row], variants: list[str], sizes: tuple[int, ...]) -> dict[tuple[str, str, int], dict[str, float]]:
    out = {}
    for v in variants:
        for pn in PROBLEMS:
            for n in sizes:
                rs = [r for r in rows if (r.variant, r.problem, r.n) == (v, pn, n)]
                if not rs:
                    continue
                ok = [r for r in rs if not r.failed]
                arr = lambda f: np.array([getattr(r, f) for r in ok], dtype=float)  # noqa: E731
                sm, s1, s3 = _q(arr("slope_ratio"))
                out[(v, pn, n)] = {
                    "log_ratio": float(np.median(arr("log_ratio"))) if ok else math.nan,
                    "slope_med": sm, "slope_q1": s1, "slope_q3": s3,
                    "n_slope": int(np.isfinite(arr("slope_ratio")).sum()),
                    "coverage": float(np.mean(arr("coverage"))) if ok else math.nan,
                    "dnlpd": float(np.median(arr("nlpd_vhgp") - arr("nlpd_gp"))) if ok else math.nan,
                    "failed": len(rs) - len(ok),
                    "n_fit": float(np.median(arr("n_fit"))) if ok else math.nan,
                    "crb": float(np.nanmedian(arr("crb"))) if ok and np.isfinite(arr("crb")).any() else math.nan,
                }
    return out


def print_table(summary: dict, variants: list[str], sizes: tuple[int, ...]) -> None:
    print("\n## Local critic calibration (median over replicates; slope ratio median [IQR] (replicates with a "
          "non-flat truth); CRB: Cramer-Rao std of the slope ratio of an oracle that knows the mean and that log r^2 is linear on the ball (median; the IQR of an efficient estimator is ~1.35 CRB wide); coverage of J~ +/- 2 r~ on fresh samples; dNLPD = NLPD(VHGP) - NLPD(GP) per replicate, median: the mean is dominated by a few GP fits that fail badly at 10-20 points)")
    head = f"{'variant':>13} {'problem':>11} {'n':>3} {'fit':>4} | {'|log r~/r|':>10} | {'slope ratio':>20} | {'CRB':>5} | {'cover':>6} | {'dNLPD':>7} | fail"
    print(head)
    print("-" * len(head))
    for v in variants:
        for pn in PROBLEMS:
            for n in sizes:
                s = summary.get((v, pn, n))
                if s is None:
                    continue
                slope = f"{s['slope_med']:5.2f} [{s['slope_q1']:.2f}, {s['slope_q3']:.2f}] {s['n_slope']:2d}"
                print(f"{v:>13} {pn:>11} {n:3d} {s['n_fit']:4.0f} | {s['log_ratio']:10.3f} | {slope:>20} | {s['crb']:5.2f} | "
                      f"{s['coverage']*100:5.1f}% | {s['dnlpd']:+7.3f} | {s['failed']}")


def targets(summary: dict, variants: list[str]) -> None:
    print("\n## Targets at 30-60 points: median slope ratio in [0.8, 1.25], IQR inside [0.6, 1.6], coverage 90-98 %")
    for v in variants:
        cells = [(k, s) for k, s in summary.items() if k[0] == v and k[2] >= 30]
        med_ok = sum(0.8 <= s["slope_med"] <= 1.25 for _, s in cells)
        iqr_ok = sum(s["slope_q1"] >= 0.6 and s["slope_q3"] <= 1.6 for _, s in cells)
        cov_ok = sum(0.90 <= s["coverage"] <= 0.98 for _, s in cells)
        nl_ok = sum(s["dnlpd"] <= 0 for _, s in cells)
        print(f"{v:>13}: median in range {med_ok}/{len(cells)}, IQR inside {iqr_ok}/{len(cells)}, "
              f"coverage in range {cov_ok}/{len(cells)}, NLPD <= GP {nl_ok}/{len(cells)}")


# (metric, panel title, format, target test or None, colour map for metrics without a target)
_PANELS = (
    ("slope_med", "slope ratio of r~ (median; 1 = right slope)", "{:.2f}", lambda v: 0.8 <= v <= 1.25),
    ("coverage", "coverage of J~ +/- 2 r~ (%)", "{:.0f}", lambda v: 0.90 <= v <= 0.98),
    ("dnlpd", "NLPD(VHGP) - NLPD(GP) (median)", "{:+.2f}", lambda v: v <= 0),
    ("log_ratio", "|log r~/r| (median; 0 = exact)", "{:.2f}", None),
)


def plot(summary: dict, variants: list[str], sizes: tuple[int, ...], path: str) -> None:
    """One heat map a metric (rows: problems, columns: n; the value printed in each cell): green
    where a cell meets the target the bench checks (at n >= 30), red where it misses it, pale
    below n = 30 (no target there); |log r~/r| shaded by size (no target)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    problems = [pn for pn in PROBLEMS if any((v, pn, n) in summary for v in variants for n in sizes)]
    fig, axes = plt.subplots(len(variants), len(_PANELS), squeeze=False,
                             figsize=(4.2 * len(_PANELS), 0.42 * len(problems) * len(variants) + 1.4))
    verdict_map = ListedColormap(["#f4c7c3", "#b7e1b0", "#fbe3e1", "#e2f3de", "#eeeeee"])
    for row, v in enumerate(variants):
        for col, (key, title, fmt, ok) in enumerate(_PANELS):
            ax = axes[row, col]
            values = np.full((len(problems), len(sizes)), np.nan)
            for i, pn in enumerate(problems):
                for j, n in enumerate(sizes):
                    if (v, pn, n) in summary:
                        values[i, j] = summary[(v, pn, n)][key]
            if ok is None:
                ax.imshow(np.abs(values), cmap="Blues", vmin=0, vmax=1.5, aspect="auto")
            else:
                # 0 miss / 1 met (n >= 30); 2 miss / 3 met below 30 (pale); 4 no value
                code = np.full(values.shape, 4.0)
                for (i, j), val in np.ndenumerate(values):
                    if np.isfinite(val):
                        code[i, j] = float(ok(val)) + (0 if sizes[j] >= 30 else 2)
                ax.imshow(code, cmap=verdict_map, vmin=0, vmax=4, aspect="auto")
            for (i, j), val in np.ndenumerate(values):
                text = "-" if not np.isfinite(val) else fmt.format(val * 100 if key == "coverage" else val)
                ax.text(j, i, text, ha="center", va="center", fontsize=8)
            ax.set_xticks(range(len(sizes)), [str(n) for n in sizes])
            ax.set_yticks(range(len(problems)), problems if col == 0 else [""] * len(problems))
            ax.set_xlabel("points in the critic's fit (n)")
            ax.set_title(title if len(variants) == 1 else f"{v}: {title}", fontsize=9)
            ax.axvline(next((j for j, n in enumerate(sizes) if n >= 30), len(sizes)) - 0.5, color="k", lw=0.8)
    fig.suptitle("VHGP critic calibration at ERSAC's sample sizes: green meets the bench's target "
                 "(n >= 30, right of the line), red misses it, pale: below 30 points", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    print(f"\nplot written to {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="6 replicates, n in {20, 45} (< 1 min)")
    ap.add_argument("--reps", type=int, default=None, help="replicates per cell (default 30, quick 6)")
    ap.add_argument("--variants", default="default", help=f"comma-separated, of {', '.join(VARIANTS)}")
    ap.add_argument("--problems", default=",".join(PROBLEMS))
    ap.add_argument("--sizes", default=None, help=f"comma-separated n (default {','.join(map(str, SIZES))})")
    ap.add_argument("--no-published", action="store_true", help="skip the whole-set comparison")
    ap.add_argument("--png", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "critic.png"))
    args = ap.parse_args()
    variants = [v for v in args.variants.split(",") if v]
    problems = [p for p in args.problems.split(",") if p]
    for v in variants:
        if v not in VARIANTS:
            ap.error(f"unknown variant {v!r}; known: {', '.join(VARIANTS)}")
    for pn in problems:
        if pn not in PROBLEMS:
            ap.error(f"unknown problem {pn!r}; known: {', '.join(PROBLEMS)}")
    reps = args.reps or (6 if args.quick else 30)
    sizes = tuple(int(v) for v in args.sizes.split(",")) if args.sizes else (20, 45) if args.quick else SIZES
    t0 = time.perf_counter()
    with threadpool_limits(1, user_api="blas"):
        print(f"# Critic calibration ({'quick' if args.quick else 'full'}; {reps} replicates per cell; variants {variants})")
        print(f"BLAS pinned to 1 thread via threadpoolctl in every process: {blas_description()}")
        print(f"load average at start {' '.join(f'{v:.1f}' for v in os.getloadavg())} (2 worker processes)")
    jobs = [(pn, n, v, s) for v in variants for pn in problems for n in sizes for s in range(reps)]
    with mp.get_context("fork").Pool(2) as pool:
        rows = pool.map(_job, jobs, chunksize=4)
    summary = summarise(rows, variants, sizes)
    print_table(summary, variants, sizes)
    targets(summary, variants)
    fails = [r for r in rows if r.failed]
    for r in fails[:5]:
        print(f"fit failed: {r.problem} n={r.n} {r.variant} seed {r.seed}: {r.failed}")

    plot(summary, variants, sizes, args.png)
    if args.no_published:
        return
    draws = 2 if args.quick else 8
    print(f"\n## Published comparison: plain VHGP on the whole set, mean |log(sigma_hat/sigma)| on 101 points "
          f"({draws} draws: median [min-max]; the authors' code, one draw each)")
    print("(default budget: up to 8 Gauss-Newton steps in lambda, then up to 12 L-BFGS-B iterations; converged: up to 1000 L-BFGS-B iterations, ftol 1e-9, gtol 1e-6)")
    for name, pub in PUBLISHED.items():
        v = published(name, draws)
        w = published(name, draws, max_iter=1000, ftol=1e-9, gtol=1e-6)
        print(f"{name:>9}: default {np.median(v):.3f} [{min(v):.3f}-{max(v):.3f}]   converged {np.median(w):.3f} "
              f"[{min(w):.3f}-{max(w):.3f}]   published {pub:.3f}")
    print(f"\ntotal wall time {time.perf_counter() - t0:.0f} s; load average at the end "
          f"{' '.join(f'{v:.1f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
