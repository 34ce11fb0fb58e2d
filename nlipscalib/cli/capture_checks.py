"""The solve's checks that ``nlips capture`` runs on the frames it captures, wired here: device/ (the session and
its exposure check) never imports solver/, and the solve's judgement is the one to give (one copy of each check).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # named in hints only
    import numpy as np

    from ..device.session import Rig


def response_slope_of(rig: Rig) -> Callable[[np.ndarray, np.ndarray], float | None]:
    """The tone-curve check of ``rig``'s captures (``device.exposure.ResponseSlope``): the solve's
    :func:`nlipscalib.solver.led_checks.recorded_response_slope` of the frames as the press the session writes
    (the rig's camera, LEDs, undeformed surface and design), every LED judged; None (not told) where the frames
    follow no power law of the model's light (:data:`~nlipscalib.core.tolerances.RESPONSE_POWER_LAW_FIT`).

    The frames it is given are in the light (a declared tone curve undone by the exposure check), so the press it
    judges declares none. The solver is imported at the first call, the session's reference (once per session:
    +0.3 s of CPU at 640x480, benchmarks/RESULTS.md, s37-capcheck); a press is not judged."""

    def slope(led_frames: np.ndarray, dark: np.ndarray) -> float | None:
        from ..core.capture import Press
        from ..core.press_meta import led_image_name
        from ..core.tolerances import RESPONSE_POWER_LAW_FIT
        from ..solver.led_checks import recorded_response_slope

        images = {"dark": "dark.png", "leds": [led_image_name(i) for i in range(len(rig.leds))]}
        press = Press(
            folder=Path("reference"),
            camera=rig.camera,
            leds=tuple(rig.leds),
            response=dataclasses.replace(rig.response, camera_response="linear", response_curve=None),
            dark=dark,
            led_images=led_frames,
            tricolor=dark,  # not read by the check
            # what the written press's meta.json holds of the sensor: the design (the dome beyond the view, for the
            # indirect light) and the provenance (the emulated sensor's scene)
            meta={"images": images, "provenance": dict(rig.provenance)}
            | ({"design": rig.design} if rig.design else {}),
            reference=rig.reference,
        )
        return recorded_response_slope(press, range(len(rig.leds)), min_fit=RESPONSE_POWER_LAW_FIT)

    return slope
