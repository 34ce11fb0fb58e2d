"""Whether a model learnt from the capture it is given: the rule behind a result's ``trained_on`` (report.json).

A model file (format 2; a lookup table's file fitted since 2026-12-07 evening) records the capture identity of every
press it was trained, validated or fitted on (``info.captures``, from its dataset's index.json); an NLiPsNet or
lookup-table result of a press records the identity of the capture it read
(``provenance.inputs.press``: SHA-256 of meta.json, every image and reference.npz). The two are compared by content,
so a press of the same name in another dataset (another session, another noise seed) is unseen, and a copy of a
trained press elsewhere is seen. ``nlips eval`` scores seen and unseen presses apart from it.
"""

from __future__ import annotations

CAPTURES_KEY = "captures"
"""A model's ``info`` key: {press name: capture identity (hex), or None where its dataset recorded none} of its
training and validation presses."""
TRAINED_ON_KEY = "trained_on"
"""A result's report.json key: :func:`trained_on`'s verdict (absent when it cannot tell)."""
TRAINED, VALIDATED, UNSEEN = "train", "validation", "unseen"
"""The verdicts: a press the model was trained on, validated on (its early stopping chose its epoch), or neither."""
SEEN = (TRAINED, VALIDATED)
"""The verdicts ``nlips eval`` counts as seen: a validation press shaped the model too, so its score is no test."""


def trained_on(info: dict, inputs: dict | None) -> str | None:
    """:data:`TRAINED`, :data:`VALIDATED` or :data:`UNSEEN`: whether the model whose ``info`` this is (a model file's)
    learnt from the capture ``inputs`` identifies (a result's ``provenance.inputs``); None when it cannot tell.

    It cannot tell when the model records no capture identities (format 1, before 2026-12-07; a lookup table fitted
    before s42-lutseen), when the input is an image frame (``{"frame": ...}``: the file's digest, not a capture's),
    and when the input matches none of the identities while some press's identity is unrecorded (that press may be
    this capture)."""
    captures = info.get(CAPTURES_KEY) if isinstance(info, dict) else None
    identity = inputs.get("press") if isinstance(inputs, dict) else None
    if not isinstance(captures, dict) or not captures or not isinstance(identity, str):
        return None
    validated = info.get("val_presses")
    validated = {n for n in validated if isinstance(n, str)} if isinstance(validated, list) else set()
    for name, known in captures.items():
        if known == identity:
            return VALIDATED if name in validated else TRAINED
    if not all(isinstance(known, str) for known in captures.values()):
        return None
    return UNSEEN
