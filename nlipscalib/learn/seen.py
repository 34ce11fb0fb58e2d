"""Whether a model learnt from the capture it is given: the rule behind a result's ``trained_on`` (report.json).

A model file trained since 2026-12-08 (s43-pressid) records the identity of every press it was trained, validated or
fitted on by what was captured (``info.press_identities``, from its dataset's index.json ``press_identity``:
:mod:`nlipscalib.core.press_identity`, the images' content and the sensor record), and ``nlips infer`` compares the
press it reads (its ``press`` digest) or the image frame it reads (its pixels, against each press's ``tricolor``
digest) with them. So a press of the same name in another dataset (another session, another noise seed) is unseen,
and a copy of a trained press elsewhere is seen, whatever its meta.json's times; an image frame whose pixels are a
trained press's tri-colour frame is seen too.

Older records: a model of format 2 without ``press_identities`` (2026-12-07), or one whose dataset recorded none
(built before 2026-12-08), is judged by ``info.captures``, the identities its presses' NLiPs solves recorded
(``provenance.inputs.press``: SHA-256 of meta.json's bytes, every image and reference.npz). That rule tells a copy of
a trained press only while its meta.json is byte for byte the same: the same press rendered or copied with another
meta.json (its ``render_seconds``) counts as unseen, which ``nlips infer`` says once (:func:`judged_by_meta`).
``nlips eval`` scores seen and unseen presses apart from the verdict.
"""

from __future__ import annotations

from ..core.press_identity import is_identity

CAPTURES_KEY = "captures"
"""A model's ``info`` key: {press name: capture identity (hex), or None where its dataset recorded none} of its
training and validation presses (the older rule, by meta.json's bytes too)."""
IDENTITIES_KEY = "press_identities"
"""A model's ``info`` key: {press name: :func:`~nlipscalib.core.press_identity.press_identity` record, or None where
its dataset recorded none} of its training and validation presses (since 2026-12-08)."""
TRAINED_ON_KEY = "trained_on"
"""A result's report.json key: :func:`trained_on`'s verdict (absent when it cannot tell)."""
TRAINED, VALIDATED, UNSEEN = "train", "validation", "unseen"
"""The verdicts: a press the model was trained on, validated on (its early stopping chose its epoch), or neither."""
SEEN = (TRAINED, VALIDATED)
"""The verdicts ``nlips eval`` counts as seen: a validation press shaped the model too, so its score is no test."""


def trained_on(info: dict, inputs: dict | None, identity: dict | None = None) -> str | None:
    """:data:`TRAINED`, :data:`VALIDATED` or :data:`UNSEEN`: whether the model whose ``info`` this is (a model file's)
    learnt from the capture it is given; None when it cannot tell.

    Parameters
    ----------
    info : the model file's ``info``
    inputs : the result's ``provenance.inputs`` (``{"press": capture identity}`` or ``{"frame": ...}``), or None
    identity : the input's :mod:`~nlipscalib.core.press_identity` record (``press_identity`` of a press folder,
        ``frame_identity`` of an image frame), or None

    By content first (module docstring): a match names the press's split; no match, with every press of the model
    recorded, is unseen. Else by the older rule (``info.captures`` against ``inputs["press"]``). It cannot tell when
    the model records neither (format 1, before 2026-12-07; a lookup table fitted before s42-lutseen), for an image
    frame when the model records no content identities, and when the input matches none of the identities while some
    press's is unrecorded (that press may be this capture)."""
    by_content = _by_content(info, identity)
    return by_content if by_content is not None else _by_capture(info, inputs)


def judged_by_meta(info: dict, identity: dict | None) -> bool:
    """Whether :func:`trained_on` judges a press with ``identity`` by the older rule only (the model records no
    content identity of some press, or none matches the input): then a copy of a trained press with another meta.json
    counts as unseen."""
    return _by_content(info, identity) is None


def _by_content(info: dict, identity: dict | None) -> str | None:
    """:func:`trained_on` by the content identities (``info.press_identities``), or None when they cannot tell."""
    known = info.get(IDENTITIES_KEY) if isinstance(info, dict) else None
    kind = "press" if is_identity(identity, "press") else "tricolor"
    if not isinstance(known, dict) or not known or not is_identity(identity, kind):
        return None
    for name, record in known.items():
        if is_identity(record, kind) and record[kind] == identity[kind]:
            return VALIDATED if name in _validated(info) else TRAINED
    return UNSEEN if all(is_identity(record, kind) for record in known.values()) else None


def _by_capture(info: dict, inputs: dict | None) -> str | None:
    """:func:`trained_on` by the older rule: ``info.captures`` against ``inputs["press"]`` (meta.json's bytes too)."""
    captures = info.get(CAPTURES_KEY) if isinstance(info, dict) else None
    identity = inputs.get("press") if isinstance(inputs, dict) else None
    if not isinstance(captures, dict) or not captures or not isinstance(identity, str):
        return None
    for name, known in captures.items():
        if known == identity:
            return VALIDATED if name in _validated(info) else TRAINED
    if not all(isinstance(known, str) for known in captures.values()):
        return None
    return UNSEEN


def _validated(info: dict) -> set[str]:
    validated = info.get("val_presses")
    return {n for n in validated if isinstance(n, str)} if isinstance(validated, list) else set()
