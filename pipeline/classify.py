"""ONNX flash classifier: tells firefly flashes from glints, lamps and headlights.

The runtime needs only numpy and onnxruntime. A model is an ONNX file plus a *model
card* (JSON) that says how to feed it: patch size, tensor layout, channel order, value
scaling and which output is the flash probability. The card is looked up, in order:

1. the path given explicitly,
2. the JSON beside the model (``model.onnx`` -> ``model.json``),
3. a card shipped in ``pipeline/models/`` for a known published model with the same
   file name (e.g. ``ffnet_gp360_65_rgb.json`` for the MATLAB-trained reference net).

Patches are uint8 RGB arrays of shape (N, S, S, 3), centred on a blob's brightest pixel
(``pipeline.patches``); ``predict`` returns the flash probability in [0, 1].
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Literal, Self

import numpy as np
import onnxruntime as ort
from pydantic import BaseModel, ConfigDict, Field, ValidationError

MODELS_DIR = Path(__file__).resolve().parent / "models"
DEFAULT_MODEL_NAME = "flashnet2.onnx"
#: Patches per onnxruntime call: beyond a few hundred the activations leave the CPU
#: caches and throughput drops (bench/bench_classifier.py).
DEFAULT_BATCH = 256


def default_model_path() -> Path:
    """Path of the ONNX model shipped with the package (its card lies beside it)."""
    return MODELS_DIR / DEFAULT_MODEL_NAME


class ModelCard(BaseModel):
    """How to feed an ONNX flash classifier and how it was made and measured.

    The network input is ``(x * scale - mean) / std`` per channel, where ``x`` holds
    the raw 0–255 patch values in ``channel_order``, laid out as ``layout``.

    ``output_kind`` says what ``output_name`` holds:

    - ``"softmax"``: class probabilities (N, K); column ``flash_column`` is the flash.
    - ``"sigmoid"``: a flash logit (N,) or (N, 1); the runtime applies the sigmoid.
    - ``"probability"``: the flash probability itself, (N,) or (N, 1).

    ``threshold`` is the probability above which a candidate is accepted as a flash.
    ``training`` records data, command and seed; ``evaluation`` the measured figures.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    input_size: int = Field(gt=0)
    input_name: str
    output_name: str
    layout: Literal["NCHW", "NHWC"] = "NCHW"
    channel_order: Literal["RGB", "BGR"] = "RGB"
    scale: float = 1.0
    mean: tuple[float, float, float] = (0.0, 0.0, 0.0)
    std: tuple[float, float, float] = (1.0, 1.0, 1.0)
    output_kind: Literal["softmax", "sigmoid", "probability"]
    flash_column: int = Field(default=0, ge=0)
    threshold: float = Field(ge=0.0, le=1.0)
    training: dict[str, Any] = Field(default_factory=dict)
    evaluation: dict[str, Any] = Field(default_factory=dict)

    @classmethod
    def from_json(cls, path: str | Path) -> Self:
        """Read a card, with an error message naming the file on any problem."""
        path = Path(path)
        try:
            return cls.model_validate(json.loads(path.read_text()))
        except OSError as exc:
            raise ValueError(f"cannot read model card {path}: {exc.strerror}") from exc
        except json.JSONDecodeError as exc:
            raise ValueError(f"model card {path} is not valid JSON: {exc}") from exc
        except ValidationError as exc:
            raise ValueError(f"model card {path} is invalid:\n{exc}") from exc

    def write_json(self, path: str | Path) -> None:
        """Write the card as indented JSON."""
        Path(path).write_text(self.model_dump_json(indent=2) + "\n")


def card_path_for(model_path: str | Path) -> Path:
    """Find the card of a model: beside it, else a shipped card of the same name.

    Raises
    ------
    FileNotFoundError
        If neither exists.
    """
    model_path = Path(model_path)
    beside = model_path.with_suffix(".json")
    if beside.is_file():
        return beside
    shipped = MODELS_DIR / beside.name
    if shipped.is_file():
        return shipped
    raise FileNotFoundError(
        f"no model card for {model_path}: expected {beside} (or a card shipped for a "
        f"known model named {beside.name} in {MODELS_DIR}); pass the card path explicitly"
    )


def center_crop_or_pad(images: np.ndarray, size: int) -> np.ndarray:
    """Bring (N, H, W, C) patches to (N, size, size, C) about their centre pixel.

    Larger sides are centre-cropped; smaller sides are padded by replicating the edge
    (as ``pipeline.patches`` clamps at the image border). The centre pixel
    ``(H // 2, W // 2)`` maps to ``(size // 2, size // 2)``, so the brightest pixel of
    an odd-sized patch stays at the centre.
    """
    if images.ndim != 4:
        raise ValueError(f"patches must be (N, H, W, C), got shape {images.shape}")
    rows = _centred_index(images.shape[1], size)
    cols = _centred_index(images.shape[2], size)
    return images[:, rows[:, None], cols[None, :]]


def _centred_index(length: int, size: int) -> np.ndarray:
    """Source indices (clamped to the edge) of a ``size`` window centred on length // 2."""
    return np.clip(np.arange(size) - size // 2 + length // 2, 0, length - 1)


class FlashClassifier:
    """A batched onnxruntime session plus the card that says how to feed it.

    Use `FlashClassifier.load`; one session is created and reused for every call.
    Implements ``pipeline.tracking.PatchClassifier``.

    Attributes
    ----------
    card : ModelCard
    input_size : int
        Side of the square patches ``predict`` accepts, in pixels.
    threshold : float
        Flash acceptance threshold on the probability, from the card.
    batch_size : int
        Patches per onnxruntime call.
    """

    def __init__(
        self, session: ort.InferenceSession, card: ModelCard, batch_size: int = DEFAULT_BATCH
    ) -> None:
        self.session = session
        self.card = card
        self.input_size = card.input_size
        self.threshold = card.threshold
        self.batch_size = batch_size
        scale = np.float32(card.scale)
        std = np.asarray(card.std, dtype=np.float32)
        # (x * scale - mean) / std folded into one multiply-add
        self._gain = scale / std
        self._offset = -np.asarray(card.mean, dtype=np.float32) / std

    @classmethod
    def load(
        cls,
        model_path: str | Path | None = None,
        card_path: str | Path | None = None,
        *,
        batch_size: int = DEFAULT_BATCH,
        threads: int | None = 1,
    ) -> FlashClassifier:
        """Open an ONNX model and its card, and check that they agree.

        Parameters
        ----------
        model_path
            ONNX file; None for the shipped default model (`default_model_path`).
        card_path
            Model card JSON; None to look beside the model, then among shipped cards.
        batch_size
            Patches per onnxruntime call.
        threads
            Intra-op threads; None for all cores. One by default: tracking classifies
            beside a decoder whose frame threads keep every core busy, where a second
            thread cost 60 % more CPU for 18 % less wall time (2 cores, 33 px patches).

        Raises
        ------
        FileNotFoundError
            If the model or its card is missing.
        ValueError
            If the card is invalid or does not match the model's inputs/outputs.
        """
        model_path = Path(model_path) if model_path is not None else default_model_path()
        if not model_path.is_file():
            raise FileNotFoundError(f"classifier model {model_path} does not exist")
        card_path = Path(card_path) if card_path is not None else card_path_for(model_path)
        card = ModelCard.from_json(card_path)
        try:
            session = ort.InferenceSession(
                str(model_path), _session_options(threads), providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own untyped errors
            raise ValueError(f"cannot load ONNX model {model_path}: {exc}") from exc
        _check_card(session, card, f"{card_path} vs {model_path}")
        return cls(session, card, batch_size=batch_size)

    def predict(self, patches: np.ndarray) -> np.ndarray:
        """Flash probability of each patch.

        Parameters
        ----------
        patches
            (N, S, S, 3) RGB patches, values 0–255 (uint8), S = ``input_size``,
            centred on the blob's brightest pixel.

        Returns
        -------
        float32 (N,) probabilities in [0, 1].
        """
        s = self.input_size
        if patches.ndim != 4 or patches.shape[1:] != (s, s, 3):
            raise ValueError(
                f"patches must be (N, {s}, {s}, 3) RGB for model {self.card.name!r}, "
                f"got shape {patches.shape}"
            )
        out = np.empty(len(patches), dtype=np.float32)
        for start in range(0, len(patches), self.batch_size):
            stop = start + self.batch_size
            out[start:stop] = self._run(patches[start:stop])
        return out

    def _run(self, batch: np.ndarray) -> np.ndarray:
        # One pass converts into the network's channel order and layout, then the
        # multiply-add runs in place (no temporaries, no copy inside onnxruntime).
        if self.card.channel_order == "BGR":
            batch = batch[..., ::-1]
        gain, offset = self._gain, self._offset
        if self.card.layout == "NCHW":
            batch = batch.transpose(0, 3, 1, 2)
            gain, offset = gain[:, None, None], offset[:, None, None]
        x = np.empty(batch.shape, np.float32)
        np.copyto(x, batch)
        x *= gain
        x += offset
        (y,) = self.session.run([self.card.output_name], {self.card.input_name: x})
        return _flash_probability(np.asarray(y), self.card)


def _session_options(threads: int | None) -> ort.SessionOptions:
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads or os.cpu_count() or 1
    opts.inter_op_num_threads = 1  # small sequential graphs gain nothing from it
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return opts


def _flash_probability(y: np.ndarray, card: ModelCard) -> np.ndarray:
    if card.output_kind == "softmax":
        y = y[:, card.flash_column]
    y = y.reshape(len(y)).astype(np.float32)
    if card.output_kind == "sigmoid":
        y = 1.0 / (1.0 + np.exp(-y))
    return y


def _check_card(session: ort.InferenceSession, card: ModelCard, where: str) -> None:
    """Raise ValueError if the card's names/shapes disagree with the ONNX graph."""
    inputs = {i.name: i.shape for i in session.get_inputs()}
    outputs = {o.name: o.shape for o in session.get_outputs()}
    if card.input_name not in inputs:
        raise ValueError(f"{where}: card input {card.input_name!r} not in model {list(inputs)}")
    if card.output_name not in outputs:
        raise ValueError(f"{where}: card output {card.output_name!r} not in model {list(outputs)}")
    shape = inputs[card.input_name]
    s = card.input_size
    expected = [3, s, s] if card.layout == "NCHW" else [s, s, 3]
    if len(shape) != 4 or any(
        isinstance(d, int) and d != e for d, e in zip(shape[1:], expected, strict=True)
    ):
        raise ValueError(
            f"{where}: model input shape {shape} does not match the card's "
            f"{card.layout} patches of {s}x{s}x3"
        )
    out_shape = outputs[card.output_name]
    if card.output_kind == "softmax":
        classes = out_shape[-1] if len(out_shape) == 2 else None
        if not isinstance(classes, int) or classes <= card.flash_column:
            raise ValueError(
                f"{where}: softmax output shape {out_shape} has no flash column {card.flash_column}"
            )
    elif len(out_shape) > 2 or (len(out_shape) == 2 and out_shape[1] != 1):
        raise ValueError(
            f"{where}: {card.output_kind} output must be (N,) or (N, 1), got {out_shape}"
        )
