"""NLiPsCalib: calibrate curved visuotactile sensors with near-light photometric stereo.

The ``nlips`` command (``nlips --help``) is built on functions a script or notebook can call (docs/api.md shows each
in a runnable example; millimetres, camera frame, docs/conventions.md):

- ``nlipscalib.core.load_press(folder)``: a capture (press folder); ``core.save_reconstruction`` /
  ``core.load_reconstruction``: results; ``core.metrics.evaluate``: a result scored against a twin's ground truth
- ``nlipscalib.solver.solve_press(press, roi="auto", indirect=reference)``: NLiPs; ``solver.calibrate_leds``: the
  LEDs fitted to the undeformed dome; ``nlipscalib.pipeline.solve_presses``: folders solved as ``nlips solve`` does
- ``nlipscalib.sim.press.render_press(scene, press, out)``: a digital-twin press (``sim.scene.load_scene``)
- ``nlipscalib.learn.dataset.build_dataset``, ``learn.train.train``: NLiPsNet's calibration;
  ``learn.infer.Predictor``: one tri-colour frame to normals, depth and points; ``learn.ply.write_ply``: a point cloud
- ``nlipscalib.device.camera.open_source``, ``device.controller.LedController``: the real sensor's camera and LEDs

Bad input raises ``nlipscalib.core.errors.NlipsError`` (a ValueError) naming the file or setting; the library prints
nothing on stdout and logs through the ``nlipscalib.*`` loggers.
"""

__version__ = "0.1.0"
