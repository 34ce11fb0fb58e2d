"""A stream's watch for frames unlike the calibration's reference: warned about once, then counted once a minute and
at the end."""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np

from ..core.errors import ShapeError, check_kind
from ..core.tolerances import FRAME_MISMATCH_FRACTION
from ..progress import RepeatedWarning
from .infer import REFRESH_REMEDY, Frame, Predictor, mismatch_warning
from .resolution import StreamSteepness

log = logging.getLogger(__name__)


class MismatchWatch:
    """An NLiPsNet predictor of stored frames that warns when frames differ from the calibration's reference
    over the whole gel (``learn.infer.mismatch_warning``: BGR stored as RGB, another exposure or sensor).

    Why: such a frame leaves the change rule nothing to find, so the maps silently show the undeformed dome.
    The warning is logged in full once, then counted once a minute (a stream of such frames would repeat it every
    frame; once per stream missed a fault that came back hours later: ``progress.RepeatedWarning``);
    :meth:`report` logs at the end how many frames it concerned, as ``nlips infer`` does: those unlike the reference
    over most of the gel, and those like it whose colours drifted (``learn.infer.drift_warning``: an aged LED group, a
    drifted exposure; their results drift by degrees), and those whose contact was too small or steep for the
    calibration (``learn.resolution.StreamSteepness``: a held press's contact measured once, each of its frames
    counted).

    Parameters
    ----------
    predictor : learn.infer.Predictor
    name : str -- the source, for the warning (``"camera 0"``, a video's path, ``"emulated sensor"``)
    in_light : bool -- the frames have the calibration's tone curve undone already
    frame_name : callable (frame index -> str), optional -- what the warnings call a frame: by default
        ``"NAME frame N"``; a watched folder's stream names its file, ``"FOLDER/NAME.png"`` (``cli._watch.frame_files``)
    """

    def __init__(
        self,
        predictor: Predictor,
        name: str,
        in_light: bool = False,
        frame_name: Callable[[int], str] | None = None,
    ) -> None:
        if not callable(getattr(predictor, "predict_stored", None)):  # a Predictor, or one standing in for it
            raise ShapeError(f"predictor must be a Predictor (Predictor(MODEL)), got {type(predictor).__name__}")
        check_kind(name, str, "name", "what the frames come from, for the messages (a str: 'camera')")
        self.predictor, self.name = predictor, name
        self.in_light = in_light
        """The frames have the calibration's tone curve undone already (a source opened with the predictor's
        ``tone_curve``: ``device.camera.to_stored``), so the predictor does not undo it again."""
        self.frame_name = frame_name if frame_name is not None else lambda index: f"{self.name} frame {index}"
        """What the warnings call frame ``index`` (settable once the source is open: ``nlips live`` makes the watch
        before it opens the source)."""
        self.frames = 0
        self.mismatched = 0
        self.drifted = 0
        """Frames like the reference but with a colour drifted past ``FRAME_CHANNEL_DRIFT`` (warned about)."""
        self.warning = RepeatedWarning(log, f"{name}: a frame unlike the calibration's reference")
        self.steep = 0
        """Frames whose contact was too small or steep for the calibration (``learn.resolution``)."""
        self.steep_warning = RepeatedWarning(log, f"{name}: a contact too small or steep for the calibration")
        self.steepness = StreamSteepness(predictor)
        """The small-contact check, measured again only when the contact changed (a held press: once)."""

    def __call__(self, frame: np.ndarray) -> Frame:
        """The predictor's result of one stored frame ((H, W, 3) uint16), warned about as above."""
        where = self.frame_name(self.frames)
        result = self.predictor.predict_stored(frame, where, in_light=self.in_light)
        self.frames += 1
        why = mismatch_warning(result, where)
        if why:
            self.warning(why, where)
        if result.mismatch > FRAME_MISMATCH_FRACTION:
            self.mismatched += 1
        elif why:  # like the reference over the gel, but its colours drifted (drift_warning)
            self.drifted += 1
        elif why := self.steepness(result, where):
            self.steep += 1
            self.steep_warning(why, where)
        return result

    def report(self) -> None:
        """The counts of frames warned about, when there were any (after the stream)."""
        self.warning.flush()
        self.steep_warning.flush()
        if self.mismatched:
            log.warning(
                "%d of %d frames differed from the calibration's reference over most of the gel (see the warning "
                "above): their results are unreliable",
                self.mismatched,
                self.frames,
            )
        if self.drifted:
            log.warning(
                "%d of %d frames had colours that drifted from the calibration's reference (see the warning above): "
                "their results drift by degrees; %s",
                self.drifted,
                self.frames,
                REFRESH_REMEDY,
            )
        if self.steep:
            log.warning(
                "%d of %d frames had a contact too small or steep for the calibration (see the warning above): "
                "their normals there are smoothed",
                self.steep,
                self.frames,
            )
