"""`python -m coopsumo.ablation` (`make learning`): what makes the shared DQN learn, one change at a time.

Two parts, both trained in free flow (3 lanes, T_up 1 s by default) and evaluated greedily on
evaluation seeds the models never trained on, beside baselines on the same evaluation seeds:

- the ablation: learner variants from the paper-literal setup to the default design, each adding
  one change to the one before (VARIANTS);
- the alpha response: the default design trained for every alpha of the grid.

A "cell" is one training seed of one variant and alpha (train, then one greedy evaluation on
evaluation seed EVAL_SEED_OFFSET + training seed) or one baseline evaluation. Cells run on the
scenario II runner (local processes or Ray), each finished cell is written atomically to
OUT/cells/<key>.json, and a rerun skips finished cells. Outputs in OUT (default
results/learning): cells/, train/<key>/, baselines/<key>/, runs.csv, summary.csv,
alpha_response.csv, fig_training_curves.png, fig_alpha_response.png, report.md.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from coopsumo.config import (
    PAPER_DQN,
    DemandConfig,
    DQNConfig,
    RewardConfig,
    RoadConfig,
    SimConfig,
    TrainConfig,
    to_dict,
)
from coopsumo.runio import Parser, UsageError, run_cli, versions, write_json
from coopsumo.studies import robustness
from coopsumo.studies.runner import add_backend_flags, check_backend, failed_exit, study_root
from coopsumo.validation import alpha_list, name_list, number_name, out_dir, seed_count, workers

EVAL_SEED_OFFSET = 1000
"""a model trained with seed s is evaluated on seed EVAL_SEED_OFFSET + s (a demand it never saw)"""
BASELINES = ("keep", "greedy", "mobil:p=0", "mobil:p=0.5")
ALPHAS = (0.0, 0.125, 0.25, 0.5, 1.0, 2.0, 8.0)
METRICS = ("mean_speed_mps", "lane_changes_per_vehicle", "lane_changes_rejected", "teleports", "collisions",
           "throughput_veh_per_h", "mean_travel_time_s")  # fmt: skip
REQUIRED_SUMMARY = ("mean_speed_mps", "lane_changes_per_vehicle", "teleports", "collisions")
"""summary values a stored cell record must hold as finite numbers to be reused (runner.record_problem)"""


def _variants() -> list[tuple[str, str, DQNConfig]]:
    """(name, what it adds, learner): a chain from the paper's learner to the default design, each
    variant the previous one plus one change, then single changes on top of the default."""
    chain: list[tuple[str, str, dict[str, Any]]] = [
        ("paper", "the paper-literal learner (--preset paper)", {}),
        ("interval", "+ a decision every 10 steps (1 s), rewards summed over it", {"decision_interval_steps": 10}),
        ("mask", "+ feasible-action masking (choice, exploration, target max)", {"action_mask": True}),
        ("double_huber", "+ double DQN target and Huber loss", {"double_dqn": True, "loss": "huber"}),
        ("adam", "+ Adam at lr 1e-3 instead of SGD at 0.01", {"optimizer": "adam", "lr": 1e-3}),
        ("replay", "+ replay 20,000 and 2 updates every decision round (not 1 every 4)",
         {"replay_size": 20_000, "learn_every": 1, "updates_per_learn": 2}),
        ("dueling", "+ a dueling Q head (V + A - mean A)", {"dueling": True}),
        ("restart", "+ 'none' withheld below 1 m/s (a standing vehicle must speed up): the default preset until "
         "the change margin (`margin`)",
         {"restart_below_mps": 1.0}),
    ]  # fmt: skip
    extras: list[tuple[str, str, dict[str, Any]]] = [
        ("eps_decay", "`restart` + epsilon decaying linearly 1.0 -> 0.05 over the first 20% of training",
         {"epsilon_start": 1.0, "epsilon_end": 0.05, "epsilon_decay_steps": 18_000}),
        ("store_all", "`restart` + every transition of a decision round stored (not 16 at random)",
         {"store_per_decision": 1000}),
        ("v2x", "`restart` + the v2x state: each side lane's nearest leader and follower within 200 m (gap, speed)",
         {"observation": "v2x"}),
        ("margin", "the `restart` models driven with a change margin of 1: a lane change only when its "
         "Q-value beats staying by more than 1", {"change_margin": 1.0}),
        ("v2x_margin", "the `v2x` models driven with the change margin of 1",
         {"observation": "v2x", "change_margin": 1.0}),
        ("select", "`margin` with model.pt chosen on held-out demand: validated greedily every 15,000 steps, the best "
         "kept (the default preset; coopsumo protocol judges it)",
         {"change_margin": 1.0, "select_every_steps": 15_000}),
        ("conditioned", "`margin` with alpha an input: one alpha-conditioned model per seed (train "
         "--alpha-conditioned), driven at each alpha (dqn:PATH,alpha=A) with the change margin of 1",
         {"alpha_conditioned": True, "change_margin": 1.0}),
    ]  # fmt: skip
    out = []
    cfg = PAPER_DQN
    for name, text, change in chain:
        cfg = replace(cfg, **change)
        out.append((name, text, replace(cfg, preset="paper" if name == "paper" else "default")))
    for name, text, change in extras:
        out.append((name, text, replace(cfg, **change, preset="default")))
    return out


CHAIN_LENGTH = 8
"""the first CHAIN_LENGTH variants form the chain paper -> ... -> restart; the rest branch off its end (margin: the
default)"""
VARIANTS = _variants()
VARIANT_NAMES = tuple(v[0] for v in VARIANTS)


@dataclass(frozen=True)
class Profile:
    """How big the study is."""

    name: str
    train_steps: int
    eval_steps: int
    seeds: tuple[int, ...]
    variants: tuple[str, ...]
    alphas: tuple[float, ...]
    alpha_variants: tuple[str, ...] = ()
    """variants whose alpha response is measured (none given: the default learner)"""
    alpha_seeds: tuple[int, ...] = ()
    """training seeds of the alpha response at alpha > 0 (none given: seeds)"""
    lanes: int = 3
    t_up_s: float = 1.0


PROFILES = {
    "full": Profile("full", 90_000, 9000, (0, 1, 2), VARIANT_NAMES, ALPHAS),
    "quick": Profile("quick", 6000, 1500, (0, 1, 2), ("paper", "margin"), (0.0, 1.0)),
    "robust": Profile("robust", 90_000, 9000, tuple(range(9)), ("restart", "v2x", "margin", "v2x_margin"),
                      (0.0, 8.0), alpha_variants=("margin", "v2x_margin"), alpha_seeds=(0, 1, 2)),
    "conditioned": Profile("conditioned", 90_000, 9000, (0, 1, 2), ("margin", "conditioned"),
                           (0.0, 0.25, 1.0, 2.0, 8.0), alpha_variants=("margin", "conditioned")),
    "tiny": Profile("tiny", 300, 200, (0, 1), ("paper", "interval", "v2x", "v2x_margin"), (0.0, 1.0)),
}


def learner_of(variant: str) -> DQNConfig:
    for name, _, cfg in VARIANTS:
        if name == variant:
            return cfg
    raise UsageError(f"unknown variant {variant!r}; expected one of {', '.join(VARIANT_NAMES)}")


def train_config(profile: Profile, dqn: DQNConfig, alpha: float, seed: int) -> TrainConfig:
    sim = SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=profile.t_up_s),
                    reward=RewardConfig(alpha=alpha), steps=profile.train_steps, seed=seed, policy="dqn")  # fmt: skip
    return TrainConfig(sim=sim, dqn=dqn, eval_steps=0)


def eval_config(profile: Profile, policy: str, seed: int) -> SimConfig:
    return SimConfig(road=RoadConfig(lanes=profile.lanes), demand=DemandConfig(t_up_s=profile.t_up_s),
                     steps=profile.eval_steps, seed=seed, policy=policy)  # fmt: skip


def training_key(dqn: DQNConfig, variant: str, alpha: float, seed: int) -> str:
    """The folder under train/ of the model that `variant` (learner dqn) drives at alpha on seed. Training ignores
    the change margin, so a variant differing from another only in it drives that one's training."""
    trained = replace(dqn, change_margin=0.0)
    if dqn.alpha_conditioned:  # one training for every alpha
        return f"{variant}_seed{seed}"
    twin = next((n for n, _, c in VARIANTS if c == trained), variant)
    return f"{twin}_alpha{number_name(alpha)}_seed{seed}"


def variant_list(flag: str, text: str) -> tuple[str, ...]:
    """The variant names of a comma-separated flag value; UsageError naming the flag unless all are known."""
    return name_list(flag, text, VARIANT_NAMES)


def cell_specs(profile: Profile, default: DQNConfig) -> list[dict[str, Any]]:
    """Every cell of the study: ablation trainings, alpha-response trainings, baselines."""
    specs: list[dict[str, Any]] = []
    seen: set[str] = set()

    def add_train(part: str, variant: str, dqn: DQNConfig, alpha: float, seed: int) -> None:
        key = f"{variant}_alpha{number_name(alpha)}_seed{seed}"
        if key in seen:
            return
        seen.add(key)
        # training ignores the margin; a conditioned one draws its own alphas (its world's alpha is 0)
        cfg = train_config(profile, replace(dqn, change_margin=0.0), 0.0 if dqn.alpha_conditioned else alpha, seed)
        cfg.validate()
        ev = eval_config(profile, "dqn", EVAL_SEED_OFFSET + seed)
        if dqn.alpha_conditioned:
            ev = replace(ev, reward=RewardConfig(alpha=alpha))
        config: dict[str, Any] = {"train": to_dict(cfg), "eval": to_dict(ev)}
        if dqn.change_margin:
            config["drive"] = {"change_margin": dqn.change_margin}
        specs.append({"key": key, "kind": "train", "part": part, "variant": variant, "alpha": alpha, "seed": seed,
                      "eval_seed": EVAL_SEED_OFFSET + seed, "policy": "dqn",
                      "train_key": training_key(dqn, variant, alpha, seed),
                      "config": json.loads(json.dumps(config))})  # fmt: skip

    for variant in profile.variants:
        for seed in profile.seeds:
            add_train("ablation", variant, learner_of(variant), 0.0, seed)
    default_name = next((n for n, _, c in VARIANTS if c == default), "default")
    responders = [(v, learner_of(v)) for v in profile.alpha_variants] or [(default_name, default)]
    for variant, dqn in responders:
        for alpha in profile.alphas:
            for seed in profile.seeds if alpha == 0 else profile.alpha_seeds or profile.seeds:
                add_train("alpha", variant, dqn, alpha, seed)
    for policy in BASELINES:
        for seed in profile.seeds:
            ev = eval_config(profile, policy, EVAL_SEED_OFFSET + seed)
            specs.append({"key": f"{policy.replace(':', '_').replace('=', '')}_seed{seed}", "kind": "baseline",
                          "part": "baseline", "variant": policy, "alpha": None, "seed": seed,
                          "eval_seed": EVAL_SEED_OFFSET + seed, "policy": policy,
                          "config": json.loads(json.dumps({"eval": to_dict(ev)}))})  # fmt: skip
    return specs


# -- one cell (in a worker process) ----------------------------------------------------------------
def new_record(spec: dict[str, Any]) -> dict[str, Any]:
    """A cell's record before it runs: coordinates and configuration, nothing measured yet."""
    from coopsumo.studies.runner import blank_record

    return blank_record(spec, ("key", "kind", "part", "variant", "alpha", "seed", "eval_seed", "policy"),
                        train_summary=None)  # fmt: skip


def failed_record(spec: dict[str, Any], error: str) -> dict[str, Any]:
    """The record of a cell whose worker died or whose task could not run."""
    from coopsumo.studies.runner import as_failed

    return as_failed(new_record(spec), error)


def run_cell(spec: dict[str, Any], root: str) -> dict[str, Any]:
    """Run one cell and return its record (never raises on failure; see runner.run_recorded)."""
    from coopsumo.studies.runner import run_recorded

    record = new_record(spec)
    cell = _run_train if spec["kind"] == "train" else _run_baseline
    return run_recorded(record, lambda: cell(spec, Path(root), record))


def _run_train(spec: dict[str, Any], root: Path, record: dict[str, Any]) -> None:
    """Train into ROOT/train/<key>/ (resuming a matching checkpoint), then evaluate greedily on the eval seed."""
    from coopsumo.agents.dqn_policy import DQNPolicy
    from coopsumo.agents.rollout import run
    from coopsumo.config import sim_config_from_dict
    from coopsumo.studies.runner import train_shared

    out = root / "train" / spec.get("train_key", spec["key"])
    record["train_summary"], _ = train_shared(spec["config"]["train"], out)  # two cells may share one training
    ev = sim_config_from_dict(spec["config"]["eval"])
    margin = float(spec["config"].get("drive", {}).get("change_margin", 0.0))
    name = f"eval_seed{ev.seed}" + (f"_margin{number_name(margin)}" if margin else "")
    spec_text = f"dqn:{out / 'model.pt'}"
    policy = DQNPolicy.from_file(spec_text[4:])
    if policy.net.conditioned:  # driven at the cell's alpha (its evaluation's)
        policy.drive_at(ev.reward.alpha, ev.road.lanes)
        spec_text += f",alpha={ev.reward.alpha:g}"
        name += f"_alpha{number_name(ev.reward.alpha)}"
    ev = replace(ev, policy=spec_text)
    eval_dir = out / name
    eval_dir.mkdir(exist_ok=True)
    policy.change_margin = margin
    summary = run(ev, policy, eval_dir, progress=False)
    record["summary"] = {k: v for k, v in summary.items() if k != "policy"}


def _run_baseline(spec: dict[str, Any], root: Path, record: dict[str, Any]) -> None:
    """One baseline evaluation into ROOT/baselines/<key>/."""
    from coopsumo.studies.runner import simulate_into

    record["summary"] = simulate_into(spec["config"]["eval"], root / "baselines" / spec["key"], spec["key"])


# -- tables ----------------------------------------------------------------------------------------
def runs_table(records: list[dict[str, Any]]) -> pd.DataFrame:
    """One tidy row per cell: coordinates, status, the evaluation metrics, training cost."""
    rows = []
    for r in records:
        s = r.get("summary") or {}
        t = r.get("train_summary") or {}
        row = {k: r.get(k) for k in ("key", "kind", "part", "variant", "alpha", "seed", "eval_seed", "status")}
        row.update({m: s.get(m) for m in METRICS})
        row.update(train_mean_speed_mps=t.get("mean_speed_mps"), train_lane_changes=t.get("lane_changes"),
                   train_wall_s=t.get("wall_seconds"), train_steps_per_s=t.get("steps_per_second"),
                   train_updates=t.get("updates"), cell_wall_s=r.get("cell_wall_s"))  # fmt: skip
        rows.append(row)
    table = pd.DataFrame(rows)
    for m in (*METRICS, "alpha", "train_mean_speed_mps", "train_wall_s", "train_steps_per_s", "cell_wall_s"):
        table[m] = pd.to_numeric(table[m], errors="coerce").astype(float)
    return table


def summarise(runs: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Mean, standard deviation and count over seeds of every metric, per group."""
    ok = runs[runs["status"] == "ok"]
    cols = [*METRICS, "train_wall_s"]
    agg = ok.groupby(by, dropna=False, sort=False)[cols].agg(["mean", "std", "count"])
    agg.columns = [f"{m}_{stat}" for m, stat in agg.columns]
    return agg.reset_index()


def is_monotone_decreasing(means: np.ndarray, sds: np.ndarray) -> bool:
    """True when no step up of the means exceeds the larger of the two neighbours' standard deviations."""
    for i in range(len(means) - 1):
        rise = means[i + 1] - means[i]
        if rise > max(np.nan_to_num(sds[i]), np.nan_to_num(sds[i + 1])):
            return False
    return True


# -- figures ---------------------------------------------------------------------------------------
def training_curves_figure(root: Path, runs: pd.DataFrame, out_path: Path) -> Path:
    """Mean speed during training (exploring) per log window, mean over seeds, one line per variant."""
    from coopsumo.report.plots import new_figure, save_figure

    fig = new_figure(9.0, 4.5)
    axes = fig.subplots(1, 2)
    ok = runs[(runs["status"] == "ok") & (runs["part"] == "ablation")]
    for variant, group in ok.groupby("variant", sort=False):
        logs = []
        for key in group["key"]:
            path = root / "train" / key / "train_log.csv"
            if path.exists():
                logs.append(pd.read_csv(path).set_index("step"))
        if not logs:
            continue
        speed = pd.concat([lg["mean_speed_mps"] for lg in logs], axis=1).mean(axis=1)
        lc = pd.concat([lg["lane_changes"] / lg["vehicles"].clip(lower=1) for lg in logs], axis=1).mean(axis=1)
        axes[0].plot(speed.index, speed.to_numpy(), label=str(variant))
        axes[1].plot(lc.index, lc.to_numpy(), label=str(variant))
    axes[0].set_xlabel("training step")
    axes[0].set_ylabel("mean speed while training (m/s)")
    axes[1].set_xlabel("training step")
    axes[1].set_ylabel("lane changes per 1,000 steps / vehicles on road")
    if axes[0].get_lines():
        axes[0].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out_path)


def alpha_response_figure(alpha_tab: pd.DataFrame, base: pd.DataFrame, out_path: Path) -> Path:
    """Lane changes per vehicle and mean speed against alpha (mean and sd over seeds), baselines as lines."""
    from coopsumo.report.plots import new_figure, save_figure

    fig = new_figure(9.0, 4.0)
    axes = fig.subplots(1, 2)
    grid = sorted(alpha_tab["alpha"].unique())
    x = np.arange(len(grid))
    for ax, metric, label in ((axes[0], "lane_changes_per_vehicle", "lane changes per vehicle"),
                              (axes[1], "mean_speed_mps", "mean speed (m/s)")):  # fmt: skip
        for variant, tab in alpha_tab.groupby("variant", sort=False):
            ax.errorbar(x[np.searchsorted(grid, tab["alpha"])], tab[f"{metric}_mean"],
                        yerr=tab[f"{metric}_std"].fillna(0), marker="o", capsize=3,
                        label=f"DQN `{variant}`")  # fmt: skip
        for _, row in base.iterrows():
            ax.axhline(row[f"{metric}_mean"], lw=0.8, ls="--", color="grey")
            ax.annotate(str(row["variant"]), (x[-1], row[f"{metric}_mean"]), fontsize=7, color="grey")
        ax.set_xticks(x, [f"{a:g}" for a in grid])
        ax.set_xlabel("alpha")
        ax.set_ylabel(label)
    if axes[0].get_lines():
        axes[0].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, out_path)


# -- report ----------------------------------------------------------------------------------------
def _fmt(mean: float, sd: float, fmt: str = "{:.2f}") -> str:
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "-"
    return fmt.format(mean) + ("" if sd is None or math.isnan(sd) else " ± " + fmt.format(sd))


def _table_rows(tab: pd.DataFrame, label: str) -> list[str]:
    rows = []
    for _, r in tab.iterrows():
        rows.append("| " + " | ".join([
            str(r[label]) if label != "alpha" else f"{r[label]:g}",
            _fmt(r["mean_speed_mps_mean"], r["mean_speed_mps_std"]),
            _fmt(r["lane_changes_per_vehicle_mean"], r["lane_changes_per_vehicle_std"], "{:.3f}"),
            _fmt(r["lane_changes_rejected_mean"], r["lane_changes_rejected_std"], "{:.0f}"),
            _fmt(r["teleports_mean"], r["teleports_std"], "{:.1f}"),
            _fmt(r["collisions_mean"], r["collisions_std"], "{:.1f}"),
            _fmt(r["throughput_veh_per_h_mean"], r["throughput_veh_per_h_std"], "{:.0f}"),
            _fmt(r["train_wall_s_mean"], r["train_wall_s_std"], "{:.0f}"),
            str(int(r["mean_speed_mps_count"])),
        ]) + " |")  # fmt: skip
    return rows


HEADER = ("| {} | mean speed (m/s) | lane changes / veh | refused requests | teleports | collisions | "
          "throughput (veh/h) | training wall (s) | seeds |\n|---|---|---|---|---|---|---|---|---|")  # fmt: skip


def report_text(profile: Profile, runs: pd.DataFrame, abl: pd.DataFrame, alpha_tab: pd.DataFrame,
                base: pd.DataFrame, meta: dict[str, Any]) -> str:  # fmt: skip
    lines = [
        "# What makes the shared DQN learn: ablation and alpha response",
        "",
        f"Profile `{profile.name}`: {profile.lanes} lanes, T_up = {profile.t_up_s:g} s, free flow; each model trained "
        f"{profile.train_steps:,} steps of 0.1 s on training seeds {list(profile.seeds)}, then evaluated greedily for "
        f"{profile.eval_steps:,} steps on evaluation seed {EVAL_SEED_OFFSET} + training seed (a demand it never "
        f"saw). Baselines run on the same evaluation seeds. Every figure is mean ± standard deviation over seeds.",
        f"{meta['cells']} cells, {meta['cells_run']} run by the last command (wall time {meta['wall_seconds']:.0f} s, "
        f"{meta['workers']} workers, {meta['backend']} backend); all cells together took "
        f"{meta.get('cell_cpu_seconds_sum', 0) / 3600:.1f} CPU hours "
        f"({meta.get('cell_wall_seconds_sum', 0) / 3600:.1f} h of cell wall time summed over cells).",
        "",
        "## Ablation: from the paper's learner to the default, one change at a time (alpha = 0)",
        "",
    ]
    for name, text, _ in VARIANTS:
        if name in profile.variants:
            lines.append(f"- `{name}`: {text}")
    lines += ["", HEADER.format("variant"), *_table_rows(abl, "variant"), *_table_rows(base, "variant"), ""]
    failed = runs[runs["status"] != "ok"]
    lines += ["![training curves](fig_training_curves.png)", ""]
    lines += robustness_lines(runs, profile)
    for variant, tab in alpha_tab.groupby("variant", sort=False):
        lines += [f"## Alpha response of `{variant}`", "", HEADER.format("alpha"), *_table_rows(tab, "alpha"), ""]
        if failed.empty:
            mono = is_monotone_decreasing(tab["lane_changes_per_vehicle_mean"].to_numpy(float),
                                          tab["lane_changes_per_vehicle_std"].to_numpy(float))  # fmt: skip
            lines.append(f"Lane changes per vehicle {'fall' if mono else 'do NOT fall'} monotonically as alpha "
                         "rises (a rise larger than the seed spread counts as a break).")  # fmt: skip
            lines.append("")
    if len(alpha_tab):
        lines += ["![alpha response](fig_alpha_response.png)", ""]
    conditioned = [v for v in profile.alpha_variants if learner_of(v).alpha_conditioned]
    for variant in conditioned:
        reference = replace(learner_of(variant), alpha_conditioned=False, preset="default")
        ref = next((n for n, _, c in VARIANTS if c == reference and n in profile.alpha_variants), None)
        if ref is not None:
            lines += robustness.conditioned_markdown(robustness.conditioned_table(runs, variant, ref), variant, ref)
    if failed.empty:
        lines += target_lines(runs, meta.get("default_variant", "replay"))
    else:
        lines += [f"**No verdict** (alpha response, targets): {len(failed)} of {len(runs)} cells failed, so the "
                  "tables above rest on fewer seeds than asked for; rerun the same command to retry them.", ""]
    ok = runs[runs["status"] == "ok"]
    bad = ok[(ok["teleports"] > 0) | (ok["collisions"] > 0)]
    lines.append(f"Safety: {len(bad)} of {len(ok)} evaluations had a teleport or a collision.")
    if len(failed):
        lines.append(f"Failed cells: {', '.join(failed['key'])}.")
    lines += ["", "Reproduce: `python -m coopsumo.ablation" + ("" if profile.name == "full" else
              f" --profile {profile.name}") + "` (finished cells are reused)."]  # fmt: skip
    return "\n".join(lines) + "\n"


def robustness_lines(runs: pd.DataFrame, profile: Profile) -> list[str]:
    """The seed-robustness section: every alpha = 0 variant judged per training seed against the baselines."""
    variants = list(profile.variants)
    table = robustness.robustness_table(runs, variants, list(BASELINES))
    if table.empty:
        return []
    per_seed = robustness.per_seed_table(runs, variants, list(BASELINES))
    return [
        "## Seed robustness at alpha = 0",
        "",
        "Each model is paired with the baselines on its own evaluation seed. Gap: model minus baseline (m/s); "
        "worst: the seed with the smallest gap; seeds below: how many models lost to that baseline.",
        "",
        *robustness.markdown(table, list(BASELINES)),
        "",
        "Mean speed (m/s) and, in brackets, lane changes per vehicle of each model by training seed (baselines: "
        "on that seed's evaluation demand):",
        "",
        *robustness.seed_matrix_markdown(per_seed),
        "",
        "![training curves per seed](fig_training_seeds.png)",
        "",
    ]


def paired_gap(
    runs: pd.DataFrame, variant: str, other: str, metric: str = "mean_speed_mps"
) -> tuple[float, float, int]:
    """Mean and sd over evaluation seeds of metric(variant, alpha 0) - metric(other), paired by seed."""
    diff = robustness.paired_gaps(runs, variant, other, metric)
    sd = float(diff.std()) if len(diff) > 1 else float("nan")
    return float(diff.mean()) if len(diff) else float("nan"), sd, len(diff)


def target_lines(runs: pd.DataFrame, default_variant: str) -> list[str]:
    """The issue's targets for the default design at alpha = 0, measured (paired by evaluation seed)."""
    lines = [f"## Targets: the default design (`{default_variant}`) at alpha = 0", ""]
    mobils = [b for b in BASELINES if b.startswith("mobil")]
    ok = runs[runs["status"] == "ok"]
    best_mobil = max(mobils, key=lambda b: ok[ok["variant"] == b]["mean_speed_mps"].mean(), default=None)
    for other, goal in (("keep", 0.5), ("greedy", 0.5), (best_mobil, -0.3)):
        if other is None:
            continue
        mean, sd, n = paired_gap(runs, default_variant, other)
        if math.isnan(mean):
            continue
        verdict = "met" if mean >= goal else f"not met by {goal - mean:.2f} m/s"
        lines.append(f"- mean speed minus `{other}`: {mean:+.2f} ± {sd:.2f} m/s over {n} evaluation seeds "
                     f"(target {goal:+.1f}: {verdict})")  # fmt: skip
    wall = ok[(ok["variant"] == default_variant) & (ok["kind"] == "train")]["train_wall_s"]
    if len(wall):
        lines.append(f"- training wall time of one model: {wall.mean():.0f} ± {wall.std():.0f} s "
                     "(measured inside its cell, with the other workers busy beside it)")  # fmt: skip
    return [*lines, ""]


def write_outputs(root: Path, profile: Profile, records: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    runs = runs_table(records)
    runs.to_csv(root / "runs.csv", index=False)
    abl = summarise(runs[runs["part"] == "ablation"], ["variant"])
    order = {n: i for i, n in enumerate(VARIANT_NAMES)}
    abl = abl.sort_values("variant", key=lambda s: s.map(order)).reset_index(drop=True)
    # the default design's alpha = 0 models are ablation cells when the default is among the variants
    responders = list(profile.alpha_variants) or [str(meta.get("default_variant"))]
    in_alpha = (runs["part"] == "alpha") | (runs["variant"].isin(responders) & (runs["alpha"] == 0))
    alpha_tab = summarise(runs[in_alpha].drop_duplicates("key"), ["variant", "alpha"])
    alpha_tab = alpha_tab.sort_values(["variant", "alpha"], kind="stable").reset_index(drop=True)
    base = summarise(runs[runs["part"] == "baseline"], ["variant"])
    pd.concat([abl.assign(part="ablation"), alpha_tab.assign(part="alpha"), base.assign(part="baseline")]).to_csv(
        root / "summary.csv", index=False
    )
    training_curves_figure(root, runs, root / "fig_training_curves.png")
    robustness.training_seeds_figure(root, runs, list(profile.variants), root / "fig_training_seeds.png")
    if len(alpha_tab):
        alpha_response_figure(alpha_tab, base, root / "fig_alpha_response.png")
    (root / "report.md").write_text(report_text(profile, runs, abl, alpha_tab, base, meta))


# -- the study -------------------------------------------------------------------------------------
def run_study(profile: Profile, root: Path, default: DQNConfig, backend_name: str = "local", workers: int = 2,
              address: str | None = None, progress: bool = True) -> dict[str, Any]:  # fmt: skip
    from coopsumo.sim.network import build_net
    from coopsumo.studies.runner import (
        cell_path,
        checked_record,
        execute,
        make_backend,
        reusable_keys,
        sigterm_interrupts,
    )

    start = time.perf_counter()
    root = root.resolve()
    try:
        (root / "cells").mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise UsageError(f"cannot write output folder {root}: {err.strerror}") from None
    specs = cell_specs(profile, default)
    done_keys = reusable_keys(root, specs, "ablation", REQUIRED_SUMMARY)
    todo = [s for s in specs if s["key"] not in done_keys]
    # the slow paper trainings first, the single changes on top of the default last; the robust profile:
    # alpha = 0 seed by seed (the tuning seeds before the held-out ones), then the alpha response
    extras = set(VARIANT_NAMES[CHAIN_LENGTH:])
    if profile.name == "robust":
        todo.sort(key=lambda s: (s["kind"] != "baseline", s["alpha"] != 0, s.get("train_key", s["key"]) != s["key"],
                                 s["seed"]))  # fmt: skip
    else:
        todo.sort(key=lambda s: (s["variant"] in extras and s["part"] == "ablation", s["kind"] != "train",
                                 s["variant"] != "paper"))  # fmt: skip
    # a training shared by several cells (margin variants, a conditioned model's alphas) is started by one cell
    # first: the others wait for it (a lock), so every training comes before every cell that would wait
    first: dict[str, str] = {}
    for s in todo:
        first.setdefault(s.get("train_key", s["key"]), s["key"])
    todo.sort(key=lambda s: first[s.get("train_key", s["key"])] != s["key"])
    default_variant = next((n for n, _, c in VARIANTS if c == default), "default")
    meta: dict[str, Any] = {"profile": asdict(profile), "default_learner": to_dict(default), "cells": len(specs),
                            "default_variant": default_variant,
                            "backend": backend_name, "workers": workers, "versions": versions()}  # fmt: skip
    print(f"ablation: profile {profile.name}: {len(specs)} cells, {len(specs) - len(todo)} already done, "
          f"{len(todo)} to run", file=sys.stderr)  # fmt: skip
    if todo:
        build_net(RoadConfig(lanes=profile.lanes))
        backend = make_backend(backend_name, workers, address, run_cell)
        try:
            with sigterm_interrupts():
                execute(todo, root, backend, len(specs), len(specs) - len(todo), progress, failed_record,
                        desc="learning cells")  # fmt: skip
        finally:
            backend.close()
    records = [checked_record(json.loads(cell_path(root, s["key"]).read_text()), REQUIRED_SUMMARY) for s in specs]
    meta.update(cells_run=len(todo), wall_seconds=round(time.perf_counter() - start, 1),
                failed_cells=[r["key"] for r in records if r["status"] != "ok"],
                cell_wall_seconds_sum=round(sum(r.get("cell_wall_s") or 0.0 for r in records), 1),
                cell_cpu_seconds_sum=round(sum(r.get("cell_cpu_s") or 0.0 for r in records), 1))  # fmt: skip
    write_outputs(root, profile, records, meta)
    write_json(root / "study.json", meta)
    return meta


def build_parser() -> Parser:
    p = Parser(prog="coopsumo learning",
               description="Ablation of the DQN learner and its alpha response (results/learning).")  # fmt: skip
    size = p.add_mutually_exclusive_group()  # one way to say the study's size
    size.add_argument("--profile", choices=tuple(PROFILES), default="full", help="study size (full: paper scale)")
    size.add_argument("--quick", action="store_true", help="the same as --profile quick")
    p.add_argument("--variants", default=None,
                   help=f"comma-separated subset of {','.join(VARIANT_NAMES)} (default: the profile's)")
    p.add_argument("--alphas", default=None,
                   help="comma-separated alpha grid of the alpha response (default: the profile's)")
    p.add_argument("--alpha-variants", default=None,
                   help="comma-separated variants whose alpha response is measured (default: the default learner)")
    p.add_argument("--seeds", type=seed_count, default=None, help="training seeds 0..N-1 (default: the profile's)")
    p.add_argument("--workers", type=workers, default=2, help="parallel cells")
    add_backend_flags(p)
    p.add_argument("--out", type=out_dir, default=Path("results/learning"))
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def profile_from_args(args: Any) -> Profile:
    profile = PROFILES["quick" if args.quick else args.profile]
    if args.variants is not None:
        profile = replace(profile, variants=variant_list("--variants", args.variants))
    if args.alpha_variants is not None:
        profile = replace(profile, alpha_variants=variant_list("--alpha-variants", args.alpha_variants))
    if args.alphas is not None:
        alphas = alpha_list("--alphas", args.alphas)
        profile = replace(profile, alphas=alphas)
    if args.seeds is not None:
        if args.seeds <= 0:
            raise UsageError(f"--seeds must be positive, got {args.seeds}")
        profile = replace(profile, seeds=tuple(range(args.seeds)))
    if args.workers <= 0:
        raise UsageError(f"--workers must be positive, got {args.workers}")
    return profile


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)

    def body() -> int:
        profile = profile_from_args(args)
        check_backend(args.backend, args.address)
        with study_root(args.out, "ablation"):  # path, lock, ownership and marker of the results folder
            meta = run_study(profile, args.out, DQNConfig(), args.backend, args.workers, args.address,
                             progress=not args.quiet)  # fmt: skip
        print(f"ablation: {meta['cells']} cells in {meta['wall_seconds']:.0f} s; report: {args.out / 'report.md'}")
        return failed_exit("ablation", meta["failed_cells"], meta["cells"], args.out)

    return run_cli("ablation", body)


if __name__ == "__main__":
    sys.exit(main())
