"""Evaluation reports: a classifier against the baselines, per data source and recording.

Every figure is reported separately for each data source (e.g. the real phone
patches and the simulated ones), because a pooled AUC would mostly measure how well
the model tells the sources apart. numpy/scipy only, so ``eval-classifier`` runs
without torch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.classify import FlashClassifier
from pipeline.training.baseline import LogisticRegression, contrast_features
from pipeline.training.calibration import choose_threshold
from pipeline.training.dataset import PatchSet
from pipeline.training.metrics import Scores, score, score_by_group

BASELINE_NAME = "contrast features + logistic regression"


@dataclass(frozen=True)
class Predictions:
    """One model's flash probabilities for every patch of a set (NaN: not applicable)."""

    name: str
    probabilities: np.ndarray
    threshold: float


@dataclass(frozen=True)
class ModelResult:
    """One model's predictions on a patch set, scored at its threshold."""

    name: str
    threshold: float
    overall: Scores
    per_group: dict[str, Scores]

    @classmethod
    def of(cls, patches: PatchSet, predictions: Predictions) -> ModelResult:
        """Score ``predictions`` of ``patches`` overall and per source recording."""
        p, t = predictions.probabilities, predictions.threshold
        return cls(
            predictions.name,
            t,
            score(patches.labels, p, t),
            score_by_group(patches.labels, p, patches.groups, t),
        )

    def as_dict(self) -> dict[str, object]:
        """For the model card: overall figures and per-recording ones."""
        return {
            "threshold": round(self.threshold, 4),
            **self.overall.as_dict(),
            "per_recording": {g: s.as_dict() for g, s in self.per_group.items()},
        }


def baseline_predictions(
    patches: PatchSet, folds: Sequence[tuple[np.ndarray, np.ndarray]]
) -> Predictions:
    """Contrast features + logistic regression, out of fold under ``folds``.

    The threshold is the most accurate one on these out-of-fold probabilities.
    """
    features = contrast_features(patches.images)
    p = np.full(len(patches), np.nan)
    for train, test in folds:
        p[test] = LogisticRegression.fit(features[train], patches.labels[train]).predict_proba(
            features[test]
        )
    return Predictions(f"{BASELINE_NAME} (grouped CV)", p, choose_threshold(patches.labels, p))


def reference_predictions(reference: FlashClassifier, parts: Sequence[PatchSet]) -> Predictions:
    """A published model's probabilities on the data sources whose patches are at
    least its input size (centre-cropped to it); NaN elsewhere, since edge-padding a
    small patch shows the model something it never saw."""
    size = reference.input_size
    p = np.concatenate(
        [
            reference.predict(part.resized(size).images)
            if part.size >= size
            else np.full(len(part), np.nan)
            for part in parts
        ]
    )
    return Predictions(f"reference {reference.card.name}", p, reference.threshold)


def compare(patches: PatchSet, models: Sequence[Predictions]) -> dict[str, list[ModelResult]]:
    """Each model's results on each data source (models without predictions there skipped)."""
    out = {}
    for source in np.unique(patches.sources):
        rows = np.flatnonzero(patches.sources == source)
        part = patches.subset(rows)
        out[str(source)] = [
            ModelResult.of(part, Predictions(m.name, m.probabilities[rows], m.threshold))
            for m in models
            if not np.isnan(m.probabilities[rows]).any()
        ]
    return out


def format_comparison(comparison: dict[str, list[ModelResult]], title: str) -> str:
    """`format_report` for each data source, one after the other."""
    return "\n\n".join(
        format_report(results, f"{title} | source: {source}")
        for source, results in comparison.items()
    )


def comparison_dict(comparison: dict[str, list[ModelResult]]) -> dict[str, object]:
    """For the model card: ``{source: {model: figures}}``."""
    return {s: {r.name: r.as_dict() for r in results} for s, results in comparison.items()}


def format_report(results: Sequence[ModelResult], title: str) -> str:
    """Text report: one summary line per model, then a per-recording table."""
    lines = [title, ""]
    header = f"{'model':58s} {'thr':>5s} {'AUC':>6s} {'acc':>6s} {'prec':>6s} {'recall':>6s}"
    lines += [header, "-" * len(header)]
    for r in results:
        s = r.overall
        lines.append(
            f"{r.name[:58]:58s} {r.threshold:5.3f} {s.auc:6.4f} {s.accuracy:6.4f} "
            f"{s.precision:6.4f} {s.recall:6.4f}"
        )
    lines += ["", "per source recording (accuracy; /AUC where both classes are present):"]
    names = " ".join(f"{f'model {i + 1}':>16s}" for i in range(len(results)))
    lines.append(f"{'recording':24s} {'n':>5s} {'flash':>5s} {names}")
    for group in results[0].per_group:
        first = results[0].per_group[group]
        cells = " ".join(_cell(r.per_group[group]) for r in results)
        lines.append(f"{group[:24]:24s} {first.n:5d} {first.n_flash:5d} {cells}")
    lines.append("models: " + "; ".join(f"{i + 1} = {r.name}" for i, r in enumerate(results)))
    return "\n".join(lines)


def _cell(s: Scores) -> str:
    auc = "" if np.isnan(s.auc) else f"/{s.auc:.3f}"
    return f"{f'{s.accuracy:.3f}{auc}':>16s}"


def held_out_summary(
    patches: PatchSet, probabilities: np.ndarray, threshold: float
) -> dict[str, dict[str, object]]:
    """Per data source, what a new user would see at ``threshold``.

    - ``auc_two_class_recordings``: ROC AUC over the recordings that hold both
      classes only (a one-class recording counts for recall or rejection, not AUC);
      ``auc_pooled`` over all its patches;
    - ``flash_recall`` over all flashes, ``background_rejection`` over all backgrounds,
      ``accuracy``;
    - ``expected_calibration_error`` and the ``reliability`` bins of the probability.
    """
    from pipeline.training.calibration import reliability
    from pipeline.training.metrics import expected_calibration_error, roc_auc

    out: dict[str, dict[str, object]] = {}
    for source in np.unique(patches.sources):
        rows = patches.sources == source
        y, p, g = patches.labels[rows], probabilities[rows], patches.groups[rows]
        two_class = np.array([len(np.unique(y[g == k])) == 2 for k in g])
        accepted = p > threshold
        flash, background = y == 1, y == 0
        out[str(source)] = {
            "n": int(rows.sum()),
            "n_flash": int(flash.sum()),
            "n_recordings": len(np.unique(g)),
            "n_two_class_recordings": len(np.unique(g[two_class])),
            "auc_two_class_recordings": _round(roc_auc(y[two_class], p[two_class])),
            "auc_pooled": _round(roc_auc(y, p)),
            "accuracy": _round(float((accepted == flash).mean())),
            "flash_recall": _round(float(accepted[flash].mean()) if flash.any() else np.nan),
            "background_rejection": _round(
                float((~accepted[background]).mean()) if background.any() else np.nan
            ),
            "expected_calibration_error": _round(expected_calibration_error(y, p)),
            "reliability": reliability(y, p),
        }
    return out


def _round(x: float) -> float | None:
    return None if np.isnan(x) else round(float(x), 4)


def format_summary(summary: dict[str, dict[str, object]], threshold: float, title: str) -> str:
    """Text table of `held_out_summary`, then the recall of each source's flashes
    (the GoPro line) and the reliability bins, one line each."""

    def f(x: object) -> str:
        return "   n/a" if x is None else f"{x:6.3f}"

    lines = [title, ""]
    header = (
        f"{'source':44s} {'recs':>4s} {'n':>6s} {'flash':>6s} {'AUC2c':>6s} {'AUCall':>6s} "
        f"{'acc':>6s} {'recall':>6s} {'reject':>6s} {'ECE':>6s}"
    )
    lines += [header, "-" * len(header)]
    for source, s in summary.items():
        lines.append(
            f"{source[-44:]:44s} {s['n_recordings']:4d} {s['n']:6d} {s['n_flash']:6d} "
            f"{f(s['auc_two_class_recordings'])} {f(s['auc_pooled'])} {f(s['accuracy'])} "
            f"{f(s['flash_recall'])} {f(s['background_rejection'])} "
            f"{f(s['expected_calibration_error'])}"
        )
    lines.append("AUC2c: over recordings holding both classes; AUCall: all patches pooled")
    lines.append("")
    for source, s in summary.items():
        lines.append(
            f"flash recall at threshold {threshold:.3f} on {source}: {f(s['flash_recall']).strip()}"
            f" ({s['n_flash']} flashes)"
        )
    lines.append("")
    lines.append("reliability (bin: n, mean predicted -> observed flash frequency):")
    for source, s in summary.items():
        bins = s["reliability"]
        assert isinstance(bins, list)
        cells = "  ".join(
            f"{b['bin']:.1f}:{b['n']} {b['predicted']:.2f}->{b['observed']:.2f}" for b in bins
        )
        lines.append(f"  {source[-40:]}: {cells}")
    return "\n".join(lines)


def plot_reliability(summary: dict[str, dict[str, object]], path: str | Path, title: str) -> None:
    """Reliability diagram (observed flash frequency vs mean predicted probability),
    one curve per data source, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.plot([0, 1], [0, 1], color="grey", lw=1, ls="--", label="perfect calibration")
    for source, s in summary.items():
        bins = s["reliability"]
        assert isinstance(bins, list)
        pred = [b["predicted"] for b in bins]
        obs = [b["observed"] for b in bins]
        sizes = [max(8.0, 60 * np.sqrt(b["n"] / s["n"])) for b in bins]
        name = Path(source).name
        ax.plot(
            pred, obs, marker="o", ms=3, label=f"{name} (ECE {s['expected_calibration_error']})"
        )
        ax.scatter(pred, obs, s=sizes, alpha=0.3)
    ax.set(xlabel="mean predicted flash probability", ylabel="observed flash frequency",
           xlim=(0, 1), ylim=(0, 1), title=title)  # fmt: skip
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def failure_montage(
    patches: PatchSet,
    probabilities: np.ndarray,
    threshold: float,
    path: str | Path,
    per_source: int = 24,
    scale: int = 3,
) -> dict[str, int]:
    """PNG of the misclassified patches, one row block per data source: rejected
    flashes (lowest probability first) then accepted backgrounds (highest first),
    each tile framed red (missed flash) or blue (false flash). Returns the number
    of failures per source."""
    import cv2

    s = patches.size
    tile = s * scale + 4
    rows_img: list[np.ndarray] = []
    counts: dict[str, int] = {}
    for source in np.unique(patches.sources):
        rows = np.flatnonzero(patches.sources == source)
        y, p = patches.labels[rows], probabilities[rows]
        missed = rows[(y == 1) & (p <= threshold)]
        false = rows[(y == 0) & (p > threshold)]
        counts[str(source)] = len(missed) + len(false)
        missed = missed[np.argsort(probabilities[missed])][: per_source // 2]
        false = false[np.argsort(-probabilities[false])][: per_source - len(missed)]
        tiles = []
        for i, colour in [(i, (255, 0, 0)) for i in missed] + [(i, (0, 128, 255)) for i in false]:
            big = cv2.resize(patches.images[i], None, fx=scale, fy=scale,
                             interpolation=cv2.INTER_NEAREST)  # fmt: skip
            framed = np.full((tile, tile, 3), colour, np.uint8)
            framed[2:-2, 2:-2] = big
            cv2.putText(framed, f"{probabilities[i]:.2f}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX,
                        0.4, (255, 255, 255), 1)  # fmt: skip
            tiles.append(framed)
        label = np.zeros((18, tile * per_source, 3), np.uint8)
        text = f"{Path(str(source)).name}: {counts[str(source)]} failures of {len(rows)}"
        cv2.putText(label, text, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
        strip = np.zeros((tile, tile * per_source, 3), np.uint8)
        for k, t in enumerate(tiles):
            strip[:, k * tile : (k + 1) * tile] = t
        rows_img += [label, strip]
    cv2.imwrite(str(path), np.concatenate(rows_img)[..., ::-1])
    return counts
