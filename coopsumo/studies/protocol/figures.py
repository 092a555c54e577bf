"""The learner protocol's figure: each training's validation over its snapshots (fig_validation.png) and its
caption."""

from __future__ import annotations

from pathlib import Path

from coopsumo.agents.training_logs import validation_table

VALIDATION_CAPTION = ("One line per training at alpha 0 (a colour per training seed; with several learners, a line "
                      "style each): at each validation snapshot of its training, the validation runs' mean speed "
                      "(left), the share of 'none' among their greedy decisions (middle) and their lane changes per "
                      "vehicle (right); model.pt holds the snapshot of the table's chosen step.")
"""fig_validation.png's caption in the report, under the figure"""
TWO_STAGE_NOTE = ("A learner whose model selection has two stages (`validation_screen`) is drawn on its screening "
                  "runs (the densest validation demand), which every snapshot ran; its diagnosis's `last` is on them "
                  "too when the last snapshot was not a finalist.")
"""added to the caption when a training of the study selected in two stages"""


def validation_curves_figure(root: Path, keys: list[str], out_path: Path,
                             names: dict[str, str] | None = None) -> Path | None:  # fmt: skip
    """Validation score and the share of 'none' among greedy decisions over training, one line per training: a
    colour per seed, a line style per learner (named by `names`, training key -> variant, when there are several)."""
    from coopsumo.report.plots import new_figure, save_figure

    tables = [(k, validation_table(root / "train" / k / "validation.csv")) for k in keys]  # checked: RecordError
    curves = [(k, val) for k, val in tables if val is not None]
    if not curves:
        return None
    fig = new_figure(10.0, 3.6)
    axes = fig.subplots(1, 3)
    seeds = sorted({key.split("_")[1] for key, _ in curves})
    learners = sorted({key.split("_", 2)[2] for key, _ in curves})  # a key: a<alpha>_seed<s>_<learner tag>
    for key, val in curves:
        _, seed, learner = key.split("_", 2)
        n = learners.index(learner)  # each seed one colour, each learner its own line style and label
        style = {"color": f"C{seeds.index(seed) % 10}", "linestyle": ("-", "--", ":", "-.")[n % 4], "marker": "o",
                 "ms": 3, "lw": 1}  # fmt: skip
        label = seed if len(learners) == 1 else f"{seed}, {(names or {}).get(key, f'learner {n + 1}')}"
        tag = "screen_" if "screen_mean_speed_mps" in val else ""  # two stages: the runs every snapshot made
        axes[0].plot(val["step"], val[f"{tag}mean_speed_mps"], label=label, **style)
        axes[1].plot(val["step"], val[f"{tag}share_none"], **style)
        axes[2].plot(val["step"], val[f"{tag}lane_changes_per_vehicle"], **style)
    for ax, label in zip(axes, ("validation mean speed (m/s)", "share of 'none' in greedy decisions",
                                "lane changes per vehicle"), strict=True):  # fmt: skip
        ax.set_xlabel("training step")
        ax.set_ylabel(label)
    handles, labels = axes[0].get_legend_handles_labels()  # beside the panels, where it hides no point
    fig.legend(handles, labels, fontsize=6, loc="center right", title="training seed", title_fontsize=7)
    fig.tight_layout(rect=(0.0, 0.0, 0.9 if len(learners) == 1 else 0.84, 1.0))
    return save_figure(fig, out_path)
