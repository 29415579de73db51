"""``results.json`` and ``results.md`` of ``ersac-hil reproduce``: every figure of the
experiments, the issue's "done when" targets with the measured value and whether each is met.

``results.json`` keeps every experiment that has been analysed in this output directory
(running ``reproduce lifting`` after ``reproduce bracing`` adds a section); ``results.md`` is
rendered from it.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

__all__ = ["load", "save", "targets", "markdown"]


def load(out: Path) -> dict[str, Any]:
    path = out / "results.json"
    return json.loads(path.read_text()) if path.exists() else {}


def save(out: Path, results: dict[str, Any]) -> None:
    results["targets"] = targets(results)
    (out / "results.json").write_text(json.dumps(_finite(results), indent=1) + "\n")
    (out / "results.md").write_text(markdown(results))


def _finite(value: Any) -> Any:
    """NaN/inf -> None (strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _target(name: str, value: Any, goal: str, met: bool) -> dict[str, Any]:
    return {"target": name, "value": value, "goal": goal, "met": bool(met)}


def _lt(a: Any, b: float) -> bool:
    return a is not None and not (isinstance(a, float) and math.isnan(a)) and a < b


def targets(r: dict[str, Any]) -> list[dict[str, Any]]:
    """The issue's "done when" items that the results cover."""
    out = []
    b = r.get("bracing")
    if b:
        n = b["paired"]["pairs"]
        need = math.ceil(0.8 * n)
        land = b["landscape"]
        damage = next(v for k, v in b.items() if k.startswith("damage_rate_last_") and k.endswith("_mean"))
        out += [
            _target("landscape: argmin mean and argmin mean + 2 std >= 0.2 apart",
                    round(abs(land["argmin_kappa_2"] - land["argmin_kappa_0"]), 4), ">= 0.2",
                    abs(land["argmin_kappa_2"] - land["argmin_kappa_0"]) >= 0.2 - 1e-9),
            _target("landscape: F2 at the two optima differs by > 3 bootstrap SE",
                    round(land["F2_gap_in_se"], 2) if land["F2_gap_in_se"] is not None else None, "> 3",
                    land["F2_gap_in_se"] is not None and land["F2_gap_in_se"] > 3),
            _target("bracing: kappa 2 final theta lower than kappa 0's", f"{b['paired']['k2_lower']}/{n}",
                    f">= {need}/{n}", b["paired"]["k2_lower"] >= need),
            _target("bracing: median paired difference (k0 - k2)", b["paired"]["median_difference"], ">= 0.1",
                    (b["paired"]["median_difference"] or 0) >= 0.1),
            _target("bracing: Wilcoxon signed-rank p (one-sided)", b["paired"]["wilcoxon_p_one_sided"], "< 0.01",
                    _lt(b["paired"]["wilcoxon_p_one_sided"], 0.01)),
            _target("bracing: kappa 2 within 0.15 of the argmin of mean + 2 std",
                    f"{b['within']['count']}/{n}", f">= {need}/{n}", b["within"]["count"] >= need),
            _target("bracing: damage rate over the last episodes, kappa 2 below kappa 0",
                    f"{damage['kappa_2']:.3f} vs {damage['kappa_0']:.3f}", "k2 < k0",
                    damage["kappa_2"] < damage["kappa_0"]),
        ]
    lf = r.get("lifting")
    if lf:
        n = lf["seeds"]
        need = math.ceil(0.8 * n)
        last = lf["stages"][-1]
        rate = lf["success_rate_pooled"][last]
        out += [
            _target(f"lifting: seeds whose {last} mean test cost is below the initial's, Welch p < 0.01",
                    f"{lf['seeds_improved_p01']}/{n}", f">= {need}/{n}", lf["seeds_improved_p01"] >= need),
            _target(f"lifting: success rate {last} (pooled over seeds)", rate, ">= 0.9",
                    rate is not None and rate >= 0.9),
        ]
    c = r.get("contexts")
    if c:
        for name, ctx in c.items():
            step = ctx["steps"][0]
            out.append(_target(f"contexts: {name}: selection lowers the re-weighted mean with no new episode",
                               step["welch_p"], "p < 0.01, no episode",
                               _lt(step["welch_p"], 0.01) and ctx["no_new_episode"]))
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "n/a" if v is None else str(v)


def markdown(r: dict[str, Any]) -> str:
    lines = ["# ersac-hil reproduce: results", ""]
    meta = r.get("meta", {})
    if meta:
        lines += [f"Sizes per experiment (this invocation: pairs {meta.get('pairs')}, "
                  f"{'quick' if meta.get('quick') else 'full'} sizes):", ""]
        lines += [f"- {exp}: `{json.dumps(values)}`" for exp, values in meta.get("sizes", {}).items()] + [""]
        for exp, t in meta.get("timing", {}).items():
            lines.append(f"- {exp}: {t['wall_s'] / 60:.1f} min of wall time, load average "
                         f"{t['load_start']:.1f} -> {t['load_end']:.1f}")
        lines.append("")
    lines += ["## Targets (issue: done when)", "", "| target | value | goal | met |", "|---|---|---|---|"]
    lines += [f"| {t['target']} | {_fmt(t['value'])} | {t['goal']} | {'yes' if t['met'] else '**no**'} |"
              for t in r.get("targets", [])]
    b = r.get("bracing")
    if b:
        lines += ["", "## Bracing", "", "Monte Carlo landscape (total cost J, bootstrap SEs):", "",
                  b["landscape"]["markdown"], "", "| run seed | final theta kappa 2 | final theta kappa 0 | "
                  "k0 - k2 | damage last, k2 | damage last, k0 |", "|---|---|---|---|---|---|"]
        dl = next(v for k, v in b.items() if k.startswith("damage_rate_last_") and not k.endswith("_mean"))
        for i, s in enumerate(b["seeds"]):
            lines.append(f"| {s} | {b['final_theta']['kappa_2'][i]:.3f} | {b['final_theta']['kappa_0'][i]:.3f} | "
                         f"{b['paired']['difference_k0_minus_k2'][i]:+.3f} | {dl['kappa_2'][i]:.2f} | "
                         f"{dl['kappa_0'][i]:.2f} |")
        p = b["paired"]
        lines += ["", f"kappa 2 lower in {p['k2_lower']}/{p['pairs']} pairs; median difference "
                  f"{_fmt(p['median_difference'])}; Wilcoxon signed-rank p (one-sided) "
                  f"{_fmt(p['wilcoxon_p_one_sided'])}; within {b['within']['tolerance']} of "
                  f"{b['within']['target_theta']:.2f}: {b['within']['count']}/{p['pairs']}.",
                  f"Fig. 2 fit on {b['fig2']['points']} episodes: argmin of J~ + 2 r~ "
                  f"{_fmt(b['fig2']['fit_argmin_F2'])}, final policy {_fmt(b['fig2']['final_theta'])}.",
                  "", "Figures: bracing_landscape.png, bracing_runs.png, fig1_critic.png, fig2_critic.png."]
    lf = r.get("lifting")
    if lf:
        learner = lf.get("learner", "the paper's Algorithm 1")  # results written before the option
        lines += ["", f"## Lifting (kappa 0, {learner})", "", "| run seed | " + " | ".join(
            f"{s}: mean +- std (success)" for s in lf["stages"]) + " | Welch p initial vs last |",
                  "|---|" + "---|" * (len(lf["stages"]) + 1)]
        for seed, ps in lf["per_seed"].items():
            cells = [f"{_fmt(ps['cost'][s]['mean'])} +- {_fmt(ps['cost'][s]['std'])} "
                     f"({100 * ps['success_rate'][s]:.0f} %)" for s in lf["stages"]]
            lines.append(f"| {seed} | " + " | ".join(cells) + f" | {_fmt(ps['welch_p_initial_vs_last'])} |")
        lines += ["", "Figures: fig4_lifting.png, lifting_learning.png."]
    c = r.get("contexts")
    if c:
        lines += ["", "## Risk contexts (kappa 2 after re-weighting)", ""]
        for name, ctx in c.items():
            lines += [f"### {name}", "", f"weights {ctx['weights']}; selected theta "
                      f"{[round(t, 3) for t in ctx['selected_theta'] or []]} after "
                      f"{ctx['episodes_before_selection']} episodes (source run: {ctx['source_episodes']}).", "",
                      "| column | mean | std | mu + 2 sigma |", "|---|---|---|---|"]
            lines += [f"| {k} | {_fmt(v['mean'])} | {_fmt(v['std'])} | {_fmt(v['mu_2sigma'])} |"
                      for k, v in ctx["columns"].items()]
            lines += [""] + [f"- {s['from']} -> {s['to']}: Welch p {_fmt(s['welch_p'])}"
                             f"{' *' if s['mean_lower'] else ''}, variance F p {_fmt(s['variance_p'])}"
                             f"{' ^' if s['variance_lower'] else ''}" for s in ctx["steps"]] + [""]
        lines += ["Figure: fig6_contexts.png."]
    return "\n".join(lines) + "\n"
