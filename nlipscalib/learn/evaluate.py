"""Scoring normal predictors on held-out presses of a calibration dataset (the same samples for every method)."""

from __future__ import annotations

import numpy as np

from ..core.metrics import aae
from .model import LoadedModel, model_inputs


def net_predict(model: LoadedModel, pixel: np.ndarray, rgb: np.ndarray, batch: int = 65536) -> np.ndarray:
    """(N, 3) unit normals of a LoadedModel for samples at ``pixel`` ((N, 2) (u, v)) with colours ``rgb`` ((N, 3),
    filtered linear: over the model's reference colours first when its ``colour_input`` is ``"ratio"``)."""
    import torch

    x = model_inputs(pixel, rgb, model.input_reference)
    out = []
    with torch.inference_mode():
        for s in range(0, len(x), batch):
            out.append(model.net(torch.from_numpy(x[s : s + batch])).numpy())
    return np.concatenate(out) if out else np.zeros((0, 3), np.float32)


def sample_scores(pred: np.ndarray, samples: dict) -> dict:
    """AAE (degrees) of ``pred`` ((N, 3)) on the contact samples, against the NLiPs and the true normals.

    ``vs_nlips`` uses the contact samples NLiPs labelled (reliable pixels); ``vs_true`` every contact
    sample with a true normal (twin presses).
    """
    contact = samples["contact"].astype(bool)
    nlips = contact & (samples["source"] == 0)
    truth = contact & np.all(np.isfinite(samples["true_normal"]), -1)
    return {
        "contact_samples": int(contact.sum()),
        "aae_vs_nlips_deg": aae(pred[nlips], samples["normal"][nlips]) if nlips.any() else float("nan"),
        "aae_vs_true_deg": aae(pred[truth], samples["true_normal"][truth]) if truth.any() else float("nan"),
    }
