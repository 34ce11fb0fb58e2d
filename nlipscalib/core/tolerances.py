"""Numerical tolerances used across the workbench, in one place (as trimesh does)."""

CONTACT_MM = 1e-3
"""A gel vertex displaced by more than this (mm) is in contact / deformed."""
SAME_LED_MM = 0.5
"""Two captures are of one sensor only if each LED sits within this distance (mm) of its counterpart (a
re-calibration moves an LED by ~0.1-0.3 mm; the twin's fingertip and NLiPsTac domes differ by 1.5 mm)."""
SAME_LED_DEG = 3.0
"""... and points within this angle (degrees) of it (a re-calibration: 1-2 deg; fingertip vs NLiPsTac: 10 deg)."""
SAME_SURFACE_MM = 0.05
"""... and their undeformed surfaces (reference.npz depth) agree within this median distance (mm)."""
OTHER_CAPTURE_DEPTH_MM = 0.3
"""``nlips eval --result R --other-capture`` scores another capture of the same press (another noise seed) only
if R's depth lies within this median distance (mm) of the press's true surface: NLiPs of a capture of the same
sensor measured 0.04 mm (160x120 twin presses), of another dome 0.7-3.0 mm (fingertip vs a copy 4 mm lower, vs
NLiPsTac)."""
SAME_INTRINSICS_RTOL = 1e-3
"""A capture is of the sensor a model or LED file was calibrated for only if its camera's fx, fy, cx, cy each agree
within this fraction (``core.sensor_record``): about a third of a pixel at 640x480 (fx 355 px, cx 320 px), so
every pixel's ray, and the (u, v) the network was trained on, stay within that; values copied from one calibration
(up to the decimals a meta.json keeps) pass, another camera's, or a re-calibration that moved them more, do not."""
SAME_INTRINSICS_ABS_PX = 1e-6
"""... or within this many pixels: the floor for a value at or near 0 (a hand-written principal point), where the
relative tolerance alone would demand exact equality. Float rounding, not a physical allowance."""
SAME_DISTORTION_ABS = 1e-3
"""... and each lens distortion coefficient within this (unitless): moves the 640x480 default fisheye's corner
pixels by 0.35 px (k1 0.05 + 1e-3), the same third of a pixel as :data:`SAME_INTRINSICS_RTOL`."""
MIN_LEDS_PER_PIXEL = 3
"""A pixel needs at least this many usable (lit, unsaturated) LEDs to be reconstructed."""
SATURATED_SHARE_WARN = 0.05
"""A capture is warned about when at least this share of the gel's samples (LED x pixel x channel) is saturated (at
or above the white level, in an LED image or the dark frame): ``nlips solve``, ``calibrate`` and ``calibrate-leds``
leave those samples out of their fits, the brightest LEDs of a pixel first, so its normal rests on the dimmer ones
(the audit's over-exposed session: 48 % of the gel's samples clipped, its LEDs calibrated to 3.5 times the images'
noise, without a word on why). ``nlips infer`` and ``live`` say it of a frame with this share of the gel's pixels
clipped."""
MIN_REFERENCE_COLOUR = 1e-3
"""Smallest reference colour (linear units) a model of ``colour_input`` "ratio" divides a gel pixel's colour by
(``learn.model.input_reference``): the gel's reference colours are 0.3-0.9; a channel the LEDs leave dark at some pixel
(a dead group, a black spot in the coat) would otherwise make its ratio infinite."""
LIT_LEVEL = 1e-3
"""An LED image gives light when its bright end on the gel (``solver.image_stats.led_levels``: the 99th percentile of
its samples) is at least this, linear units (full scale 1) above the dark frame; a dead LED's image says nothing
about the light, and the solvers and the LED calibration leave it out.

Not the capture's exposure check (:data:`EXPOSURE_LIGHT_FRACTION`, :data:`EXPOSURE_LIT_SHARE`), on purpose: that
one asks, while the session can still be fixed, whether an LED is lit as driven, on raw frames of a camera that
may have 8 bits, where this level is a quarter of one step (1/255) and a lens cap's noise would pass it; it
blurs the noise away and asks for 2 % of full scale (5 steps at 8 bits), 20 times this. This one asks, of a
capture that can no longer be retaken, whether an image holds any light to fit: a dim LED still constrains the
normals (the fit weighs it against the images' noise), so only an image with almost nothing above the dark frame
is dropped. The capture check is the stricter: a frame it calls lit has 1 % of the gel 20 times above this level,
and one between the two is warned about at capture but still fitted."""
DEAD_LED_FRACTION = 0.005
"""An LED image is also dead when its bright end (as :data:`LIT_LEVEL`'s) is below this fraction of the median LED
image's: it then holds the dark frame's noise, not light. Why: :data:`LIT_LEVEL` alone is below the noise's own
bright end (a dead LED's image, a dark frame plus read noise, measured 0.0012 on the one-bounce 640x480 twin, the
lit ones 0.65-0.87): that LED was fitted as lit, its dark image misfit the undeformed model all over the gel, and
``nlips solve --roi auto`` refused the press with "found no contact" (s26 QA walk). An LED at 1 % of the others'
power (bright end ~0.006 on the tests' synthetic dome) stays lit: it still constrains the normals."""
DARK_FRAME_OFFSET = 0.005
"""A dark frame whose median on the gel lies more than this (linear units, full scale 1) from the sensor's black
level is not a dark frame of that sensor: above it, it holds light (an LED image saved as the dark frame: it was
solved on to "no pixel could be reconstructed ... dead LEDs [1]"), and the solve is refused; below it, meta.json's
``sensor.black_level`` is not the sensor's (a dark frame of zeros added 1.6 % of full scale to every image and
moved the twin's cube press from 0.42 to 0.72 deg without a word), and the solve is warned about. The twin's dark
frames: within 1e-4 of it."""
DARK_PEDESTAL_SPREAD = 0.5
"""A dark frame above the black level by more than :data:`DARK_FRAME_OFFSET` whose gel samples spread (5th to 95th
percentile) less than this share of that offset is even, as a camera's undeclared black level (pedestal) is: the
refusal names ``--black-level`` first (an LED left lit or room light falls off across the dome by more than its
own level; the twin's 64-DN pedestal read as black level 0 spreads 0.09 of it, noise, at 160x120)."""
NORMAL_EPS = 1e-9
"""Norms below this are treated as zero when normalising (float64 vectors: an LED's direction, a LUT bin's mean
normal, a radiosity patch's area-weighted normal; any real one is many orders of magnitude longer, so the
value changes no number). The networks' float32 torch normalisation keeps its own 1e-8 (``learn.model``,
mirrored as ``min_norm`` in the ONNX export, whose parity depends on it)."""
EXPERIMENT_CHECK_ABS = {"aae_deg": 0.5, "mabse": 0.005, "depth_rmse_mm": 0.05}
"""``nlips experiment --check``: an accuracy figure is worse when it exceeds the baseline by more than
max(this absolute amount, EXPERIMENT_CHECK_REL x baseline) (units: degrees, unitless, mm)."""
EXPERIMENT_CHECK_REL = 0.10
"""Relative part of the ``--check`` tolerance (fraction of the baseline value)."""
INDIRECT_MIN_SHARE = 0.02
"""Interreflection ``auto``: the indirect term is applied when its fitted share of the direct light on the
undeformed dome (median over the gel) is at least this; below it the capture has no measurable indirect light."""
GATHER_CLUSTER_RATIO = 0.25
"""The radiosity gather on a patch grid (:func:`nlipscalib.solver.radiosity.gather_grid`) lights a tile of receivers
with a cluster of emitter patches as one aggregate patch when the cluster's radius is below this fraction of its
distance to every receiver of the tile (the cluster's angular radius below ~14 deg), and patch by patch otherwise.
Why this value: the aggregate's form factor errs by about the square of that ratio relative (a point-to-patch
form factor evaluated at the centroid), and an error of the indirect light at most ~1 % near a dent moved no
solve: on the default twin's 640x480 one-bounce sphere and cube presses the gathered light of a solved surface
was within 1e-2 (max) / 1e-3 (median) of the exact gather, the undeformed dome's within 2e-5 (the inside of a
sphere is the degenerate case where the form factor does not depend on the distance), and contact and all-pixel
AAE within 0.0013 deg of the exact gather's, whole frame and auto ROI (benchmarks/RESULTS.md), with a fifth of
the pairwise terms. 0.15 halves the error for 1.7 times the terms."""
VISIBILITY_HEIGHT_MM = 0.05
"""The interreflection gather's visibility test (:func:`nlipscalib.solver.radiosity._hidden`): a surface patch
between two others hides them from each other when it stands more than this (mm) on the camera's side of their
segment. Why a margin: patch centroids lie a little off the surface they average, and a solved surface's noise
ripples by hundredths of a millimetre; a flat or concave surface then never hides itself."""
INDIRECT_PATCH_USABLE = 0.99
"""Interreflection fit (:func:`nlipscalib.solver.indirect.fit_indirect`): a patch enters the fit, for an LED and
a channel, only when more than this share of its area is usable (on the gel, unsaturated, its LED lit, outside
``exclude``): in effect, wholly usable. What it guards: the patch's mean image counts its unusable pixels as
dark, so a partly usable patch (the gel's edge, a saturated glint, a contact's rim) would read too dim by the
unusable share and pass for less light than it has; the margin below 1 keeps a wholly usable patch whose
area-weighted mean rounds to just under 1. The value's own origin is not recorded."""
INDIRECT_FIT_MIN_SHARE = 0.3
"""An explicit ``--roi`` box without an undeformed capture: the press's own interreflection fit leaves the box out
(the contact is in it) only when at least this share of the patches it can fit on over the whole gel lie outside it
(:func:`nlipscalib.solver.indirect.fit_patch_share`); a box over more of the gel (the whole frame: none left) is fitted
as a whole-gel solve is, away from the contact it finds (``solver.light_and_contact``). Why: a fit on the ring of
patches along the frame's edge that a big box leaves comes out low (the twin's one-bounce 640x480 sphere press:
coating reflectance 0.837 on the whole gel; 0.832, 0.827, 0.823, 0.815 with 49, 36, 26, 16 % of the patches left)
and the solve with it worse than with the whole gel's fit: with 16 % left (a box over 90 % of the frame's side) the
contact's depth RMSE +0.011 mm on the sphere press, its AAE +0.015 deg on the cube press, at 640x480 and 320x240
alike; with 26 % +0.006 mm on the sphere; with 36 % +0.003 mm, the AAE within 0.003 deg (benchmarks/RESULTS.md,
s32-wholebox). Between the last two: a box that leaves more keeps its own fit (and its results)."""
ANCHOR_NOISE_FACTOR = 3.0
"""Anchoring: a pixel is undeformed when its misfit to the undeformed model is within this many times the
misfit that the estimated image noise alone explains."""
CONTACT_MISFIT_FACTOR = 3.0
"""Contact: a pixel is hit (in or at the contact: ``--roi auto``'s box, the dent focus of the outer interreflection
loop, the pixels a press's own indirect fit leaves out; :func:`nlipscalib.solver.contact_verdict.contact_hits`) when its
misfit exceeds this many times the larger of its noise-only misfit and the misfit's median over the gel. Why: the
floor is at least the noise-only misfit, so a hit pixel is never one anchoring calls undeformed (as long as this is
at least :data:`ANCHOR_NOISE_FACTOR`); the median raises it where the undeformed model is not exact on a real
sensor (then most of the gel misfits above noise level and only a dent's misfit stands out by this factor); and the
RMS of noise alone over a pixel's LEDs and channels (tens of samples) stays well within 3 times its expected value,
so noise alone does not make hits."""
CAMERA_SHIFT_PX = 0.5
"""A press whose image is shifted by at least this many pixels against its undeformed capture is warned about (the
camera moved: :mod:`nlipscalib.solver.camera_shift`). Why: since s42-shift1px (6 LEDs, a second pass) the 135
presses of q3 (five designs; sphere, cube and screw; 640x480, the one-bounce twin, whose camera never moves) measure
0.01-0.38 px in place (median 0.08), and moved by sub-pixel shifts (``cv2.warpAffine``) of 0.5-3 px they read to
within 0.38 px: a 1 px move 0.68-1.28 px. At 0.75 px (before) a 1 px move could pass unwarned (it read 0.62-1.29 px:
7 of the bench's 116 1 px moves); a 0.5 px move may or may not be warned (benchmarks/RESULTS.md, s42-shift1px)."""
NO_CONTACT_PEAK = 8.0
"""``--roi auto``: a press has no contact when no pixel's misfit reaches this many times its floor (the floor of
:data:`CONTACT_MISFIT_FACTOR`): the press is then refused with "found no contact", not solved on the whole gel. Why:
noise and model error alone make hits at :data:`CONTACT_MISFIT_FACTOR` scattered over the gel (the twin's
undeformed capture solved as a press: 1,528 pixels, the box 100 % of the gel, peak 4.7 times the floor; the
fingertip twin's at 320x240, 8 spp: 4.8), while the twin's presses peak at 12.6-67 times it (sphere1, cube1, coin1,
the demo's three, six more; s26-degen2). It was 6 from s26-falsealarm to s27-shapesfa: at s26-degen2's 8 the
fingertip twin's 1 mm cube press against its undeformed capture peaked at 7.5 and was refused; 8 again since
s27-shapesfa, which found noise alone at 6.06 (the fingertip's undeformed capture at 320x240, 16 spp, as a press
with its design LEDs: solved as a press) and such dents caught by their patch (below). Only where the images fit
the model to noise (:data:`MODEL_MISFIT_FLOOR`); a patch of hits of a dent's size away from the gel's edge
(:data:`NO_CONTACT_PATCH`) is a contact however low its peak (the capsule design's cube and cylinder
presses against their undeformed capture: 5.4 and 4.5; s27-shapesfa). With the design's LED model as the undeformed
model the peak is over the floor and the point-LED model's known error together (:data:`LED_EMITTER_RADIUS_MM`):
the capsule's undeformed captures at 320x240 / 16 spp peaked at 8.0-10.1 in the image corners, where its wall comes
within 4.4 mm of an LED, and 7 of 8 were solved as presses; over both, 6.1-6.7 (s28-capsule)."""
NO_CONTACT_PATCH = 0.002
"""``--roi auto``: a press has a contact, whatever its peak (:data:`NO_CONTACT_PEAK`), when its hits at
:data:`CONTACT_MISFIT_FACTOR` make a connected patch of at least this share of the gel's pixels that does not
touch the gel's edge (``solver.contact_verdict.no_contact``). Why: a faint dent misfits little per pixel over many;
noise's and model error's hits are specks, or lie along the edge (grazing view). Measured at 320x240
(s27-shapesfa): dents 0.31 % (the fingertip's 0.3 mm sphere, 8 spp, design LEDs: peak 6.6), 0.65-3.1 % (the
capsule's cube and cylinder, peaks 4.5-6.5); noise and model error at most 0.06 % inside the edge (undeformed
captures as presses: capsule, ring16, default twin; second captures against the first: none)."""
RESOLVED_TILT_PER_PX = 0.9
"""A press's contact is too small for the solve to resolve when the solved normals' tilt from the undeformed surface
(its 75th percentile over the contact's hits, degrees) exceeds this many degrees per pixel of the contact's
equivalent diameter (the largest component of :data:`CONTACT_MISFIT_FACTOR` hits among the solved pixels): the
solve then warns that the normals there are smoothed (``solver.resolution``). Why: the depth's smoothing spreads a
dent over a few pixels whatever its size, so the error grows with how steeply the normals turn per pixel, not with
the size alone (a 1 mm sphere 0.3 mm deep and a 6 mm sphere 0.05 mm deep are both ~10 px across at 320x240; 3.6 and
0.8 deg). Measured on 16 twin sphere presses, 1-6 mm, 0.05-2 mm deep, 320x240 and 640x480, ``--roi auto``
(benchmarks/RESULTS.md, s28-tiny): 1.11-2.28 deg/px scored 1.66-3.62 deg contact AAE; 0.09-0.36 deg/px scored
0.45-0.78 deg; the tests' exact 96x72 sphere and cube dents 0.71 and 0.45 (0.11 and 0.57 deg). The threshold is near
the geometric middle of 0.71 and 1.11."""
CHANGED_TILT_PER_PX = 0.4
"""``nlips infer`` warns that a frame's NLiPsNet normals in its contact are smoothed when its predicted normals'
tilt from the undeformed surface (75th percentile over the largest patch of the change rule's changed pixels less
their 4 px rim, ``learn.resolution.measure_contact``) exceeds this many degrees per pixel of that patch's equivalent
diameter (``core.steepness``, the formula of :data:`RESOLVED_TILT_PER_PX`). Lower than the solve's 0.9: the net errs
more than the solve on such contacts (s27-unusual: 5.6 against 2.4 deg on the 1 mm sphere at 640x480). First measured
with a 32-32 net trained 5 min on /tmp/keep/train50 (640x480; benchmarks/RESULTS.md, s28-tinynet): 1-2 mm spheres
0.1-0.5 mm deep 0.59-1.28 deg/px, contact AAE 3.2-5.7 deg; 15 normal and unusual presses 0.05-0.17 deg/px and the
6 mm sphere 0.05 mm deep 0.29 (1.3 deg). Re-measured with the measure as it is now (notches closed, holes filled;
s40-steep) for Q2 full's 256-256-128 net on 20 twin spheres 1-6 mm, 0.05-0.8 mm deep, and sphere1/cube1/coin1 at
640x480: the error rises with the figure without a knee (normal presses 0.85-0.99 deg; 0.16-0.26 deg/px 1.0-1.7;
0.32-0.37 1.8-2.0; 0.44-0.47 2.6-3.4; 0.57-1.14 3.3-8.0). Why 0.4: it parts the presses the net errs on by 2.5 times
a normal press's error or more (0.44 deg/px and up) from those it errs on by less (0.37 and below), at their
geometric middle, as s28 parted 3.2 from 1.3 deg; parted at twice the error it would be 0.29. The tests' 96x72 twin's
6 mm sphere: 0.55 (warned). A lookup table's results are held to :data:`TABLE_CHANGED_TILT_PER_PX`; their warning
names the table's own step (``learn.resolution.model_words``)."""
TABLE_CHANGED_TILT_PER_PX = 0.3
""":data:`CHANGED_TILT_PER_PX` for a lookup table's normals (``nlips lut``, ``learn.resolution.ModelWords``). Why
lower: a table's normals are its bins' means and stop at its bins' steepest, so a small steep contact reads flatter on
them than on a net's (Q2 full's table, 16 levels, 8x8 regions: the 1 mm sphere 0.5 mm deep 0.45 deg/px on its normals,
0.79 on the net's, 0.98 on the truth; 0.8 mm deep 0.33, 0.44, 0.50: its tilts stop at 18-21 deg, near the
calibration's steepest labels' 22.6, where the truth's are 27-40), while its error keeps rising (25.7 and 15.6 deg).
Measured on the same presses as the net's figure (s40-steep): the table errs by 3.6-5.6 deg on normal presses (median
4.9), 6.2-8.6 at 0.14-0.28 deg/px of its own normals and 9.8-25.7 at 0.33-0.70; 0.3 is the geometric middle of 0.28
and 0.33, which parts its presses at twice its normal error and warns every one it errs on by 2.5 times (0.4 left
the 1 mm sphere 0.8 mm deep, 15.6 deg, unwarned by the rule). Both figures rest on the twin's 640x480 Q2 calibration
only; its calibration check (1.5 times the steepest press, 0.14 deg/px there) warned every one of these small
presses for both models."""
UNCALIBRATED_STEEPNESS_FACTOR = 1.5
"""``nlips infer`` warns that a frame's NLiPsNet normals are not to be trusted when its contact (the change rule's
largest patch, ``learn.change``) turns its predicted normals by more degrees per pixel of its equivalent diameter
(75th percentile of the tilt over the diameter, ``core.steepness``) than this times the steepest calibration
press's labels did (recorded at training by the same measure, ``learn.resolution.measure_contact``), or more than
:data:`CHANGED_TILT_PER_PX`. Why: the net extrapolates, and smooths like the labels it learned, past the presses it
was taught; a margin over the steepest press, since one frame's normals are not its labels: Q2 full's 50
calibration presses through their net read 0.945-1.014 times their recorded figure, a 5-press net's 5 presses
0.97-1.00 (s39-steepwarn); the 50-press twin calibration reached 0.72 deg/px with two shallow cone presses, above
every sphere press tried. benchmarks/RESULTS.md (s28-tinynet, s39-steepwarn)."""
STREAM_CONTACT_CHANGE = 0.03
"""A stream's frame (``nlips infer`` of a camera or video, ``nlips live``) gets the last judged frame's verdict of
:data:`CHANGED_TILT_PER_PX` (``learn.resolution.StreamSteepness``) instead of its contact being measured again when
its changed pixels number within this fraction of that frame's and their centroid lies within this fraction of that
frame's equivalent diameter (at least a pixel) of that frame's: the same press held. Why: the measure costs 2-4.5 ms
of host CPU per pressed 640x480 frame, and a held press's frames differ by the sensor's noise only (sphere1 with its
noise doubled: pixels within 0.5 %, centroid within 0.4 px; benchmarks/RESULTS.md, s29-watchcost)."""
STREAM_TILT_CHANGE = 0.03
"""... and when its contact's normals turn (``learn.resolution.contact_bend``: the sum of 1 - cos(tilt) over about
:data:`STREAM_TILT_SAMPLES` of its pixels) within this fraction of that frame's: a press that steepens or flattens
in place, its changed pixels kept, is measured again on its first frame past it (it kept the last verdict for up to
:data:`STREAM_REJUDGE_FRAMES` frames: sphere1's normals steepened 2 % a frame went unwarned 28 frames after the
still-frame check warned). A held press's sum wanders 0.27-0.35 % with its noise added again (sphere1, cube1, coin1
at 640x480: a tenth of this); benchmarks/RESULTS.md, s34-live."""
STREAM_TILT_SAMPLES = 1000
"""Pixels of a contact :data:`STREAM_TILT_CHANGE` samples, about: every k-th row and column of its box with k the
square root of its pixels over this (``learn.resolution.bend_step``, chosen when the contact is measured; every
pixel of a contact under 4 times this), so that a held press costs about the same whatever its size: 0.013-0.014 ms
of CPU a frame for sphere1, cube1 and coin1 at 640x480 (steps 5-8; every pixel 0.13-0.28 ms, the measure 1.3-2.7
ms), their sums wandering 0.27-0.35 % with the frames' noise added again (benchmarks/bench_stream_rejudge.py,
s34-live)."""
STREAM_REJUDGE_FRAMES = 30
"""... for at most this many frames in a row, then measured again (a second at 30 frames/s): a change neither the
changed pixels nor the tilt tell (a steep spot inside a press held still) is not judged once for the whole stream."""
MODEL_MISFIT_FLOOR = 3.5
"""A press's images fit the undeformed model only to within model error, not noise, when the misfit's median over
the gel is at least this many times the noise-only misfit: :data:`NO_CONTACT_PEAK` (a peak over noise) then says
nothing, and a press is called without contact only when no pixel is hit at :data:`CONTACT_MISFIT_FACTOR` (and then
told to calibrate the LEDs, not that it matches the dome). Why: a real LED ring's power spread raises the floor
everywhere, and the dent stands out by less than 8 times it: the twin's cube press with LED powers 5 / 10 / 15 %
off the design (design LEDs, no undeformed capture) peaked at 7.2 / 3.9 / 2.8 (floor 10 / 20 / 30 times the noise),
sphere1 and coin1 at 15 %: 4.7 and 5.4, and all were refused as "no contact" though the dent was plain (17,000-43,000
hits); the realistic twin without its refracting gel, LEDs 0.3 mm and 3 deg off their design, solved with the
design: 12.9-14.4 times the noise, its 1 mm sphere and cube presses peaked at 6.7 and 4.4 (4.9-5.3 with the true
LEDs: the extended LEDs, glossy coat and response curve are not in the model either). The twin's presses and
undeformed capture: 1.8-2.5 times the noise (the realistic twin at 8 spp, whose noise is the renderer's: 2.4-2.5)
(benchmarks/RESULTS.md, s26-falsealarm)."""
SENSOR_MISFIT_SHARE = 0.08
"""A press is refused as taken with another sensor than its meta.json and reference.npz describe (dome, camera,
LEDs) when the undeformed model, with a gain fitted per LED (a power spread is the sensor's own), misses its images
by at least this share of their brightness (the median over the gel of each pixel's RMS misfit over the median
pixel's level; :attr:`nlipscalib.solver.contact.ContactMap.sensor_fit`), and by at least :data:`MODEL_MISFIT_FLOOR`
times the noise (below that the misfit is the noise's, not the model's). Why (320x240 one-bounce twins, 8 spp): the
default dome's images with the fingertip design's files miss by 12 % (the reverse 18 %), with the capsule's, flat's
or oblate's 16-36 % (and those designs' images with the default's 18-29 %); every twin with its own files 0.6-2.0 %
(default, fingertip, oblate, capsule, flat; the default with its LED powers 15 % off: 1.7 %), the realistic twin
without its refracting gel, LEDs 0.3 mm and 3 deg off the design, 3.2-3.9 %; the realistic twin at 8 spp 8.8 %, all
of it noise (2.5 times the noise: not refused). Designs closer than that are not told apart: the fingertip's and the
capsule's images through each other's files 5.0-5.8 %, a fingertip dome 4 mm lower 3.0 % (benchmarks/RESULTS.md,
s27-sensorfit)."""
SENSOR_MISFIT_BEST_SHARE = 0.04
"""... and only when the best-fitting tenth of the gel misses by at least this share too (the 10th percentile of the
pixels' misfits, same unit). Why: where a press covers most of the view (a crop around a dent, a large flat
indenter) the median misfit is the dent's (a 64x64 crop of a synthetic sphere press: 25 %), but the undeformed
rest still fits its own sensor's model: 0.5-2.4 % on the twins of :data:`SENSOR_MISFIT_SHARE` (real_norefr 2.4 %);
another design's files 4.9-8.3 % (the default dome with the fingertip's: 4.9 %, the thinnest margin; s27-sensorfit)."""
SENSOR_FIT_VIEW_DEG = 30.0
"""... and only when the view sees the dome at large: the camera's rays through the gel reach this far (degrees)
from their mean direction. Why: a view of a patch of the dome (a 64x64 crop of a 480x360 view around a dent, a test's
"mostly dent" capture, 9.5 deg) can be all dent, and a dent misfits the undeformed model as another sensor does
(25 %); the shipped designs' full views reach 52-68 deg."""
ROI_LARGE_FRACTION = 0.5
"""``--roi auto``: a box covering at least this fraction of the gel's bounding box is "most of the gel": the
components along the gel's edge are then left out when a large one lies inside, or the user is warned."""
ROI_MIN_UNDEFORMED_SHARE = 0.1
"""``--roi auto``: the box is widened (by its margin at a time) until at least this share of its gel pixels fit the
undeformed model within :data:`ANCHOR_NOISE_FACTOR` times the noise: they anchor the solved depth to the reference.
Why: a 6 mm sphere 3 mm deep (the gel's thickness) deforms the gel far beyond the pixels that misfit by
:data:`CONTACT_MISFIT_FACTOR` times the raised floor; its box held 3 % such pixels and its contact AAE was 1.51 deg,
depth RMSE 0.25 mm (the whole gel: 0.88 deg); widened to 16 %, 0.98 deg and 0.09 mm. The twin's other presses hold
17-44 % at the 8-pixel margin (coin1 17 %, cube1 23 %, sphere1 27 %) and keep their box (benchmarks/RESULTS.md,
s27-unusual). Not widened where the whole image holds no larger share than the box (the realistic twin: 3.3 % in the
dent's box, 2.8 % in the image, whose corners misfit; widened, 3.95 deg contact AAE against 3.14; s32-docwalk)."""
ROI_FLANK_FACTOR = 1.5
"""``--roi auto``: a pixel shows a contact's flank when its misfit exceeds this many times its floor (the floor of
:data:`CONTACT_MISFIT_FACTOR`); the box grows while the 4-px strip beyond it holds :data:`ROI_FLANK_SHARE` of such
pixels (``solver.contact_flank.grow_over_flank``). Why: a large flat indenter moves the gel far beyond the pixels hit at
:data:`CONTACT_MISFIT_FACTOR`: the 20 mm coin face 0.3 mm deep (320x240 twin) misfits by 1.5-4 times the floor over a
20-30 px flank, and its box left out 36 % of its ground-truth contact (now 15 %: 7 % of its main patch, plus a patch
the twin moves by 1 um along the image's bottom border, 9 % of the truth) (benchmarks/RESULTS.md, s28-bigedge)."""
ROI_FLANK_SHARE = 0.03
"""... the share of a strip's pixels above :data:`ROI_FLANK_FACTOR` times the floor that makes it flank; the first
strip without it stops that side. Why: the coin's flank strips hold 6-81 %, 4-px strips of undeformed gel beside the
twin's dents 0-3 %."""
ROI_FLANK_START = 0.05
"""... the first strips lie this share of the image's short side beyond the contact's hits (12 px at 320x240, 24 at
640x480). Why: closer in, a plain dent's weak rim and the change of its light around it pass as flank: at 0.033 the
640x480 coin1 box grew 238x238 -> 238x262 px with its truth boxed already, and its contact AAE went 4.642 -> 4.673
deg with a larger box; at 0.05 sphere1, cube1 and coin1 keep their boxes, the 20 mm coin boxes 93 % of its main
patch (95 % at 0.033-0.04 with the factor 1.4, coin1 then 261x261)."""
ROI_FLANK_MAX_CONTACT_MISFIT = 9.0
"""... and only a contact whose pixels (those the box holds) misfit by a median of less than this many times the floor:
a large shallow contact, whose images differ little from the undeformed dome's (the twin's 16-20 mm coin faces
0.2-0.5 mm deep at 320x240: 4.0-8.2). Why: a plain dent misfits more (6-20 mm spheres, the 640x480 coin1: 9.7-17.4),
and against an undeformed capture (``--reference``, no model error in the floor) the change of its light around it
passed as flank: coin1's box grew 238x240 -> 302x268 px (+20 % solve CPU, contact AAE 4.484 -> 4.512 deg), the
320x240 6 and 12 mm spheres' 16 px (benchmarks/RESULTS.md, s31-autobox)."""
LED_EMITTER_RADIUS_MM = 1.8
"""``--roi auto``: radius, mm, of the disk an LED is taken to emit from when judging the misfit along the gel's edge
that the auto ROI leaves out (``solver.point_led_error.point_led_misfit``): edge pixels that misfit by no more than
:data:`CONTACT_MISFIT_FACTOR` times what the point-LED model leaves against such disks are that model's known error,
not a fault, and are left out without a warning; likewise for :data:`NO_CONTACT_PEAK` (s28-capsule). Why: the
solver models point LEDs; a WS2812B emits from a light
cup about 3.6 mm across (the twin's default ``[led_package]``), whose light the point model misses by a few % where
the gel comes within a few LED sizes of the LEDs -- the ``capsule`` design's wall at the image border (every press
with the design LEDs warned of 1,300-2,000 edge pixels; rendered with point LEDs its undeformed capture has 22 hits
against 2,464; s27-shapes2). Not read from the capture: the press format does not describe the LED package."""
POINT_LED_SPREAD_FOR_DISKS = 0.008
"""A solve with the capture's own LEDs (no ``--leds`` file) under ``--led-model auto`` (the default), on a design that
declares its LEDs' size (``leds.emitter_diameter``): where the point LEDs miss the disks' light over the gel by more
than this spread (:func:`nlipscalib.solver.point_led_error.point_led_spread`, the std of log(disk / point)), the LEDs
are solved as those disks, points otherwise (:func:`nlipscalib.pipeline.led_choice.auto_led_diameter`).
Why: the flat pad (0.0145) and the oblate dome (0.0135) lose most to points: the twin's flat cube pressed 1 mm at
polar 25 deg, contact AAE 0.889 deg with the design's point LEDs, 0.238 as disks (0.262 with LEDs calibrated as
points); oblate 0.437 -> 0.298 (s42-flatauto). Since the interreflection gather's visibility test the fingertip
(0.0096) gains as disks on every press measured, 13 of 13, by 0.065-0.31 deg (contact AAE 1.343 -> 1.233 deg, depth
24.7 -> 17.0 um rms; s43-autodisks2), so the level sits below it (0.012 before) and above the hemisphere's (0.0072;
its 12 LEDs alone 0.0067-0.0073, the fingertip's 0.0076-0.0107), which stays on points: there the disks gain on
spheres, cubes and cylinders (16 presses, 0.478 -> 0.439 deg, the worst +0.004) but lose on every coin, 0.028-0.074
deg (whole frame up to 0.145; docs/experiments/RESULTS.md)."""
POINT_LED_SPREAD_LIT = 0.05
""":func:`nlipscalib.solver.point_led_error.point_led_spread` uses the gel an LED lights above this share of its median
shading: at grazing light the ratio of two near-zero shadings is noise, not the model's error."""
ROI_MIN_INNER_FRACTION = 0.005
"""``--roi auto``: a misfit component away from the gel's edge counts as a dent, in favour of which the edge's
are left out, when it holds at least this fraction of the gel's pixels (96 px at 160x120, 1,536 at 640x480:
well above isolated hot pixels and shadow specks, below a 3 mm sphere's contact)."""
MAX_MEDIAN_DISPLACEMENT_MM = 3.0
"""A solve whose median distance to the undeformed surface exceeds this (mm; the default gel is 3 mm thick,
and a median over a region around a contact is far below the deepest point) has left the physically
possible range: :func:`nlipscalib.solver.solve_press` re-solves without the noise-adapted smoothness."""
OUTER_TOL_DEG = 0.05
"""The outer interreflection loop (:func:`nlipscalib.solver.solve_press`) is settled when the median normal change
of a pass falls below this, degrees; one refined pass over the whole mask then ends it. Why: the relaxed loop's
changes fall by a factor of about 0.1-0.3 per pass on a smooth dent (2.55, 0.29, 0.04 deg on the 640x480 twin's
sphere press, benchmarks/RESULTS.md), so a pass that moved the normals by less than this leaves them within about
0.02 deg of the loop's fixed point, below what a further NLiPs solve is worth. On the cube press they fall by only
about 0.5 per pass, alternating (the light feeds back through the solved shape as well as the albedo, which the
relaxation does not hold: s16-f's section), and the default ``max_outer`` ends the loop before this is reached."""
DENT_FOCUS_MARGIN = 0.05
"""The outer interreflection loop's passes before the last solve the auto ROI's box widened by this fraction of the
image's short side (24 px at 640x480): the dent's light changes most around it."""
DENT_FOCUS_SHARE = 0.5
"""... when that box covers less than this fraction of the solve's mask (a whole frame); otherwise every
pass solves the whole mask."""
DENT_FOCUS_MIN_PIXELS = 1024
"""... and when it holds at least this many pixels of the mask (a 32 x 32 box, the auto ROI's least): a contact
outside an explicit ROI leaves nothing to focus on."""
CALIBRATION_MIN_PIXELS = 100
"""LED self-calibration needs at least this many pixels of the gel (all captures, after ``stride``): about ten
per parameter of an LED (9). With one pixel (``--stride 10000``) half the LEDs came out NaN and the fit
called itself reliable."""
CALIBRATION_MIN_LED_KEPT = 0.5
"""The LED calibration leaves an LED image's lagged or dark band (its rows read before its LED switched, or while
it was off) out of that LED's fit (:mod:`nlipscalib.solver.calibration_bands`) when at least this share of the gel's
pixels is left to it; a larger band is refused (capture again). Why half: the twin's undeformed capture (320x240, one
bounce, 16 spp; its clean fit's LED 5 disk 0.055 mm / 0.68 deg off the truth) with LED 5's rows from LED 4, fitted on
the rest: bands at the top leaving it 73-44 % of the gel 0.023-0.032 mm / 0.34-0.52 deg, 27 % 0.065 / 0.99, 15 % 0.168 /
1.86; at the bottom (where LED 5 lights the gel brightest) 73 % 0.214 / 1.24, 48 % 0.322 / 1.74, 27 % 0.379 /
2.51, every one called reliable (its own residual 1.02-1.05x the noise): over half left, every band tried stayed
within the README's 0.3 mm / 2 deg (benchmarks/RESULTS.md, s31-darkleft)."""
CALIBRATION_MIN_SHARE = 0.1
"""LED calibration, interreflection auto: the indirect term is used when, fitted with the starting LEDs,
its share of the direct light is at least this. The starting LEDs' own errors pose as a few % of
indirect light (a nominal ring 0.3 mm / 5 deg off: 3 %); a coated dome interreflects far more (the
twin: 31 %). The images cannot decide it after the fact: a direct-only fit absorbs the indirect light
into wrong LED parameters (17 deg off on the twin) and then fits as well as the right model."""
CALIBRATION_MIN_TERM_GAIN = 16.0
"""LED calibration, interreflection auto, the term on by :data:`CALIBRATION_MIN_SHARE`: it is kept when, converged,
it lowers the point LED fits' summed squared residual by more than this many noise variances against a
direct-only fit on the same samples (:func:`nlipscalib.solver.calibration_term.term_gain`); otherwise the LEDs are
fitted as direct light. Why: starting LEDs 0.8 mm / 10 deg off pose as 11-20 % of indirect light on a bounce-free
capture, and the term then left the worst LED 7.4-11.9 deg off (direct-only 0.45-0.67). Why this value: a term that only
fits noise gains about a chi-squared with its 3 parameters (the reflectance per channel): 16 is its 99.9 % point.
Measured (s17-d, benchmarks/RESULTS.md; 160x120 stride 4 one bounce, stride 2 bounce-free): one-bounce twin, 12 seeds x
3 starts, 407-1757 (log: mean 7.0, sd 0.46 over the seeds: 9 sd above ln 16; in the gain itself 2.6 sd); bounce-free
with noise, 6 seeds x 6 starts that turned the term on, -5117 to -1670; noise-free -1.8e5 and below; the 640x480
one-bounce reference 2262-2480."""
CALIBRATION_CONTACT_FRACTION = 0.005
"""LED calibration: a capture is taken to show a contact (a press, not the undeformed dome it must be; refused unless
``--allow-contact``) when a connected region of pixels that the fitted undeformed model misfits
(:func:`nlipscalib.solver.contact_verdict.contact_hits`) holds at least this fraction of the gel's pixels (as
:data:`ROI_MIN_INNER_FRACTION` for ``--roi auto``). Why: measured with the LEDs the calibration fits (2026-12-06),
the largest such region of an undeformed capture holds at most 0.15 % of the gel (the oblate twin's, direct-only fit
leaving its interreflection; 0-0.03 % on the default twin bounce-free or one-bounce, 80x60 to 640x480, the
realistic twin and the emulator's reference), that of a press at least 3 % (a 3 mm sphere 0.5 mm deep at polar 30
deg, 160x120; 10-23 % for the default sphere, coin and cube presses): a factor 3 or more either side. Noise-free
renders: 0 % undeformed (the LED model's own error, :data:`CALIBRATION_MODEL_ERROR`, counted as noise), 3.4 % for
that small press at 80x60."""
CALIBRATION_ONE_LED_MISFIT = 4.0
"""LED calibration: a misfit region of a capture (:data:`CALIBRATION_CONTACT_FRACTION`) is put down to one LED's light
that the point model does not describe (an LED far from its design, near the gel), not to a press, when that LED's
image holds at least this many times its fair share (1 / the LEDs) of what a normal per pixel leaves unexplained
(:func:`nlipscalib.solver.calibration_contact.unexplained_shares`). Why: measured (2026-12-06, 12 LEDs): presses
1.7-2.5x (the twin's sphere and cube at 320x240, the synthetic sphere and cube), an LED near the gel 6.3x (the 160x120
twin, its LEDs 4 mm / 35 deg off the design) and 8.5-9.5x (a 3.6 mm disk LED 3.5-5.3 mm from the synthetic dome): a
factor 1.6 either side (benchmarks/RESULTS.md, s28-ledfar). With 4 LEDs or fewer it never applies."""
CALIBRATION_MODEL_ERROR = 0.003
"""LED calibration quality (:func:`nlipscalib.solver.calibration_quality.fit_quality`): the error the LED model itself
is allowed, as a fraction of each LED's median lit sample, added to the images' noise in quadrature. Why: the model
samples the shading at the pixel's centre while a pixel integrates its footprint (and a render its few samples),
a smooth error that Immerkaer's noise estimate cannot see; without noise it is all the residual there is. The
twin's noise-free bounce-free renders (4 spp, 80x60 and 160x120, stride 2) leave 0.24-0.28 % with LEDs 0.43-0.61
deg off (points; disks 0.07-0.16 deg) and were rated 1.52-1.56x, unreliable; with 0.3 % they are 0.71-0.80x.
It stays small against what the verdict must catch: a noise-free one-bounce 16 spp render with the term on
leaves 0.93 % (LEDs 1.7-3.1 deg, 0.31-0.36 mm off: still 2.9x), and on captures with the sensor's noise
(2.2-3.8 % of that level) it moves the ratio by at most 0.01 (measured 2026-12-05: the table in
:func:`nlipscalib.solver.calibration_quality.fit_quality`)."""
FIT_NOISE_RATIO = 1.15
"""An LED calibration is reliable when its residual is at most this many times the images' own noise (with the
model's own error, :data:`CALIBRATION_MODEL_ERROR`; median over the LEDs): measured 1.01-1.11 on good captures,
1.19-1.63 on poor ones (the table in :func:`nlipscalib.solver.calibration_quality.fit_quality`)."""
LED_FIT_OUTLIER_RATIO = 1.5
"""One LED of a calibration called reliable (:data:`FIT_NOISE_RATIO`, the median LED's) is warned about when its own
residual is above this many times the images' noise: the worst single LED of good twin captures reached 1.13
(:func:`nlipscalib.solver.calibration_quality.fit_quality`), LEDs stopped in a wrong minimum 1.6-92
(benchmarks/RESULTS.md, s27-ledstarts)."""
FRAME_MISMATCH_FRACTION = 0.04
"""NLiPsNet: a frame whose median difference from the calibration's reference frame over the gel exceeds this
fraction of the reference's brightness differs almost everywhere (twin frames of presses: 0.009-0.011, 8-bit
ones too; 5 % brighter: 0.052; red and blue swapped: 0.28; a dark frame: 1.0), so its changed pixels cannot be
told apart and the result is warned about."""
FRAME_CHANNEL_DRIFT = 0.025
"""NLiPsNet: a frame whose median red, green or blue on the unchanged gel is off the calibration's reference frame's
by more than this fraction is warned about even when it is otherwise like it (:data:`FRAME_MISMATCH_FRACTION`):
an LED group dimmed with age, or the exposure or gain drifted. Twin presses as captured measured at most 0.8 % off
(30 presses, 640x480) and 0.2 % (96x72, 1 spp); one LED group 2 % dimmer cost 0.6-0.8 deg of contact error, 3 %
1.2-1.6 deg and 5 % 3 deg, silently before this check (benchmarks/RESULTS.md, s28-ageing)."""
REFRESH_SMOOTHING_PX = 2.0
"""NLiPsNet's refresh from a new undeformed frame (``learn.infer.Predictor.refresh``): both reference frames are
smoothed on the gel with a Gaussian of this sigma, pixels, before their ratio, so one frame's noise is not copied
into every frame's colours (the drifts it corrects -- LED ageing, exposure, a scuffed coating -- are smooth)."""
REFRESH_GAIN_LIMIT = 2.0
"""NLiPsNet's refresh: each pixel's gain is clipped to [1/this, this]; a sensor that changed by more needs a new
calibration, not a refresh."""
REFERENCE_PRESS_SHARE = 0.0025
"""NLiPsNet's refresh (``nlips infer --reference FRAME``): a frame offered as the undeformed sensor shows a press
when one patch of at least this share of the gel both changed by the change rule (:data:`CHANGE_NOISE_SIGMAS`) and
changed colour beyond what per-LED gains and a smooth field explain (:mod:`nlipscalib.learn.reference_press`). At
160x120: twin and emulated presses 1.2-22 % (a 6 mm sphere 0.15 mm deep the least); 0 for clean references of other
seeds and of the emulated camera, each LED alone at 30-99 %, a colour group at 90-95 %, all LEDs at 80 %, 1-5 %
noise and a 10-25 % darker scuff (benchmarks/RESULTS.md, s34-inferref)."""
REFERENCE_COLOUR_FIELD = 0.08
"""... the smooth field left in the colours once the LEDs' gains are out: Gaussian sigma, this fraction of the image's
width (without the LEDs' shares, 0.15 left patches up to 5 % of the gel by one LED at half its light, 0.08 at most
1.1 %)."""
REFERENCE_COLOUR_SIGMAS = 5.0
"""... a pixel's colour stands out of that field beyond the gel's median distance by this many robust sigmas ..."""
REFERENCE_COLOUR_MIN = 0.01
"""... and by at least this much (log ratio, about 1 % of a colour's share)."""
FRAME_BLACK_FRACTION = 0.01
"""NLiPsNet: a frame that differs from the calibration's reference frame over most of the gel
(:data:`FRAME_MISMATCH_FRACTION`) and whose median brightness on the gel is at most this fraction of the
reference's is called black in the warning (no light above the black level: LEDs off, a lens cap, a camera not
streaming); a black frame below the calibration's dark frame would otherwise read as a negative number of times
as bright."""
FRAME_BRIGHTNESS_OFF = 0.15
"""NLiPsNet: a mismatched frame (:data:`FRAME_MISMATCH_FRACTION`) whose median brightness is off the reference's by
more than this fraction is called darker or brighter in the warning (another exposure, LED level or bit depth);
otherwise the colours differ."""
CHANGE_NOISE_SIGMAS = 5.0
"""NLiPsNet's change rule (:mod:`nlipscalib.learn.change`, and its GPU copy in :mod:`nlipscalib.learn.fullframe`:
the calibration dataset's contact, the pixels inference sends through the network): a block has changed when
its averaged colour difference exceeds the median by this many noise sigmas."""
CHANGE_MIN_REL = 0.005
"""... and exceeds this fraction of the reference's intensity (shading noise floor)."""
CHANGE_GAIN_TRIM_SIGMAS = 3.0
"""NLiPsNet's change rule takes the frame's per-colour gain out before its second pass (rule 3,
:func:`nlipscalib.learn.change.rule_gain`): the median ratio of frame to reference over the gel blocks its first
pass left unchanged, again over those within this many robust sigmas (1.4826 MAD) of it in every colour, so that
the blocks of a large contact the first pass missed, far out, do not pull it (a synthetic contact over 35 % of the
gel in a frame 1 % off: 0.4 % off the frame's gain with one median, 0.03 % with both)."""
INTEGRATION_MIN_FACING = 0.05
"""Least -n.d a normal is integrated with (:mod:`nlipscalib.learn.integrate` and its torch copy; it faces the
camera at most ~87 deg from its ray). A visible surface faces the camera; a network's normal that is grazing or
faces away (an untrained model, a frame of another sensor) would give a slope without bound and overflow the
depth, so it is clipped to this grazing slope instead."""
TORCH_INTEGRATION_PARITY_MM = 5e-4
"""Depth (mm) of the torch integrators (:mod:`nlipscalib.learn.integrate_torch`, any device, either sine
transform) and the CPU's (:mod:`nlipscalib.learn.integrate`) agree within this where they solve the same boxes:
float32 rounding of the transforms (at 640x480, 2 mm dents: up to 2.3e-4 mm in the middle, 1.2e-4 at the image
border; solving the whole gel instead of an edge box moved border contacts by 2-4e-3 mm, s25)."""
INTEGRATION_AMG_RTOL = 1e-8
"""Relative residual (|b - M x| / |b|) at which the sparse path's AMG-preconditioned CG stops
(:func:`nlipscalib.learn.integrate_sparse._solve_amg`, large regions). At 1e-8 its depth is within 3e-6 mm of SuperLU's
on the default dome's cross and the flat pad's whole gel (640x480), far inside :data:`TORCH_INTEGRATION_PARITY_MM`; at
1e-6 the cross was already 1.6e-4 mm off, too near it (s27-amgpath)."""
ONNX_PARITY_DEG = 0.1
"""An ONNX export is accepted when onnxruntime's normals are within this angle (degrees) of PyTorch's
(:func:`nlipscalib.learn.onnx_export.checked_parity`); at or beyond it the export is refused. What it guards: an
export that computes something other than the network (a wrongly fused layer, a missing normalisation), while
the two runtimes' float32 rounding passes. The value's own origin is not recorded."""
ONNX_WEIGHT_TOL = 1e-5
"""A received ONNX file's weights are its model's (:func:`nlipscalib.learn.onnx_export.check_export`) when each
differs from the model's folded float32 weight by at most this fraction of the layer's largest weight: float32
rounding of the folding (done in float64) on another machine or torch version, while weights of another model (or
a trained-on copy) differ by far more. Exports of the same loaded model are bit-identical (difference 0)."""
UNIT_NORMAL_TOL = 1e-3
"""A stored normal's length may differ from 1 by this much (float32 storage rounds at ~1e-7)."""
FACING_AWAY_MAJORITY = 0.5
"""Normals are flipped when more than this share of the sampled gel faces away from the camera
(:mod:`nlipscalib.core.surface_checks`; a convention, not a tolerance: a file that follows it faces the camera
everywhere, one with flipped normals nowhere)."""
SURFACE_SCALE_RATIO = 20.0
"""A capture's undeformed surface (reference.npz) and ground truth lie, in median, within this factor of its LEDs'
median distance from the camera (the shipped sensors: 1.3-2.4 times; depth written in metres: 1/1000)."""
EXPOSURE_LIGHT_FRACTION = 0.02
"""Capture exposure check: a pixel is lit by an LED when its LED frame exceeds the dark frame by more than this
fraction of full scale (mean of the channels after the :data:`CAPTURE_CHECK_BLUR` box blur, which averages the
sensor noise away; an 8-bit camera: 5 DN). The emulated nlipstac sensor's dimmest LED lights 99 % of the gel
above 0.11, a median pixel at 0.23; a frame with the LEDs off, or a lens cap, stays within noise of the dark
frame. Twenty times the solver's :data:`LIT_LEVEL`, which asks another question (why: there)."""
CAPTURE_CHECK_BLUR = 5
"""Side, pixels, of the box blur of a capture's checks on raw frames (the exposure check's lit pixels, the
session's movement check), and of the blocks the repeated-frame check averages (:data:`REPEATED_FRAME_DIFFERENCE`):
25 pixels averaged cut the sensor noise 5 times, while a lit gel or a moved edge, many pixels wide, keeps its
level."""
EXPOSURE_LIT_SHARE = 0.01
"""... an LED frame is black (no light above the dark frame: the LED off or dead, a lens cap, the camera not
looking at the gel) when fewer than this fraction of the gel's pixels are lit by it (a lit LED of the shipped
sensors lights all of them)."""
EXPOSURE_SATURATED_SHARE = 0.05
"""... a frame (an LED frame or the tri-colour frame) is over-exposed, and the capture warns naming it and
suggesting a shorter exposure or a lower LED level, when more than this fraction of the gel's pixels are at the
white level in a channel: those pixels are dropped by every solver (their light is unknown), so a few
specular glints pass and a clipped patch does not (the audit's over-exposed session: 54 % of LED 1's gel, 100 %
of the tri-colour frame's)."""
EXPOSURE_UNUSABLE_SHARE = 0.99
"""... the reference is refused (not written; the session's settings are not yet fixed, so it can be captured
again at another exposure) when every LED frame is black or has at least this fraction of the gel saturated:
nothing downstream can use it (LED calibration and NLiPs read the LED frames, and NLiPs solves label NLiPsNet's
training)."""
CAMERA_SETTING_RTOL = 0.02
"""A live camera's setting (exposure, gain, white balance, frame size, ...) is taken as applied when the value it
reads back is within this fraction of the one asked for (:func:`nlipscalib.device.camera.apply_settings`);
otherwise it is reported as refused. What it guards: a camera that ignores or clamps a setting is named rather
than trusted, while one that stores the value in its own units and reads back a slightly rounded number passes.
The value's own origin is not recorded."""
CAMERA_SETTING_ABS = 1e-6
"""... or within this absolute amount (the setting's own units): the floor for a value of 0 (raw frames off,
auto exposure/gain/white balance off), where the relative tolerance alone would demand exact equality. Float
rounding, not a physical allowance."""
EXPOSURE_READBACK_RANGE = 4.0
"""An exposure time a live camera reads back within this factor of the one asked is taken as the time it took
(:func:`nlipscalib.device.camera.reported_exposure_ms`: a shutter table of its own, 1/60 s for 16 ms; a minimum,
1 ms for 0.5); further off, as no time at all (OpenCV's 0 or -1 where a backend reads nothing back): the asked one
is kept."""

VIDEO_FRAME_COUNT_SLACK = 2
"""Frames a recorded video may end short of the count its container declares (with
:data:`VIDEO_FRAME_COUNT_SLACK_SHARE`, the larger of the two) before it is taken as truncated."""
VIDEO_FRAME_COUNT_SLACK_SHARE = 0.05
"""A recorded video whose frames end more than this many frames, and more than this share of the count its
container declares (OpenCV's ``CAP_PROP_FRAME_COUNT``), before that count is taken as truncated or damaged
(:class:`nlipscalib.device.camera.OpenCVSource`: one error line after the frames read, not a quiet end). Why the
slack: where a container holds no exact count (Matroska, a variable frame rate) FFmpeg estimates it from the
duration and frame rate, a frame or a few percent off; a copy cut short or a recording stopped by a full disk
loses far more (a 21-frame MJPEG AVI cut to 15 kB read 9 frames and ended with exit 0 before)."""
CAMERA_CAL_MIN_TILT_SPREAD_DEG = 5.0
"""Camera calibration (:mod:`nlipscalib.device.camera_calibration`): views whose boards all face the same way
(normals within this angle, deg) cannot separate the focal length from the board's distance: the fit then returns
any focal length (4 copies of one view gave fx 2944 px for a 640 px wide camera, at 0.7 px error), so such a set
is refused."""
CAMERA_CAL_HIGH_RMS_PX = 1.0
"""A camera calibration whose reprojection error (RMS, px) exceeds this is reported as poor (good ones: 0.02-0.3
px)."""
COVERAGE_GEL_SHARE = 0.25
"""Coverage report (:mod:`nlipscalib.learn.coverage`): an image region counts as gel, and is asked to be covered
by presses, when at least this share of its pixels sees the gel. What it guards: a region that only grazes the
gel's edge would otherwise count as an empty region that no press can fill, and the next press would be sent
there. The value's own origin is not recorded."""
REFINE_LED_SHARE = 2 / 3
"""Per-pixel normal refinement (:mod:`nlipscalib.solver.refine`, ``SolverOptions.normals = "refined"``): the share
of the (live) LEDs fitted at each pixel, its brightest ones. Why: next to a relief's wall the grazing LEDs are in
cast shadow, which the solve's shadow threshold (1 % of an image's bright end) keeps and a robust weight only
halves. On the default twin's three 640x480 one-bounce coin presses (prototype, auto ROI, contact AAE) 8 of 12
LEDs gave 3.85 / 3.99 / 3.83 deg, 9 of 12 3.91 / 4.08 / 3.98, 7 of 12 within 0.02 deg of 8; all 12 (the first
press) 4.21; the plain solve 4.69 / 4.79 / 4.64 (benchmarks/RESULTS.md)."""
REFINE_GATE = 2.0
"""... a pixel takes the refined normal only when it lowers the Cauchy energy of the fitted samples by more than
this (energy / lambda^2). Why: the depth's normal is right to a few tenths of a degree on smooth contact, the
per-pixel fit only to the images' noise (ungated: the twin's sphere and cube presses 0.52 -> 1.02 and 0.43 -> 0.95
deg). With lambda ~3 sigma a correct depth normal gains ~chi2(2) / 9 from the fit's two extra degrees of freedom,
so 2 is a chi-square of ~18 (p ~1e-4). Measured: 1 switched 0.5 % of the sphere's and cube's contact (+0.01 deg),
2 none of the sphere's and 2 of the cube's 90 000 pixels; on the coin 1 and 2 scored alike, 4 lost 0.07 deg."""
REFINE_ITERATIONS = 6
"""... reweighting iterations of each pixel's fit, from the depth's normal. Why: 12 moved the coin press's contact
AAE by 0.02 deg against 6 (without the gate); each costs one 3x3 solve per pixel."""
MAX_LED_DISTANCE_MM = 1000.0
"""An LED read from a file (meta.json, an LED file) sits at most this far (mm) from the camera: a visuotactile
sensor's LEDs are ~10 mm away. Why: a file from elsewhere with a position of 1e30 mm solved to "no contact found"
instead of naming the value (docs/formats.md, "Files from others")."""
MAX_LED_MU = 1000.0
"""... its anisotropy ``mu`` is at most this (a beam of 3 deg to half power; the twin's LEDs: 1): ``(n_s . d)^mu``
of mu = 1e9 underflows to zero off the axis, a dark LED the file does not say it is."""
MAX_LED_INTENSITY = 1e6
"""... and its intensity Psi (linear image units x mm^2) at most this per channel: calibrated LEDs are ~1 (the
images' full scale is 1 at ~10 mm); all LEDs at 1e30 overflowed the solver's float32 model (no contact found)."""
MAX_IMAGE_PIXELS = 1 << 24
"""Images (PNG headers) and cameras read from files hold at most this many pixels (16.8 Mpx: 4096 x 4096, twice a
4K camera's 3840 x 2160). Why: a PNG of zeros deflates ~1000:1, so an 840 KB file decoded to 1.7 GB (12000 x 12000,
16-bit RGB) in 10 s, and a press of 13 such images with a meta.json of that camera size asked for 22 GB; OpenCV's
own limit (``CV_IO_MAX_IMAGE_PIXELS``, 2^30 pixels: 6.4 GB at 16-bit RGB) ends in a traceback (docs/formats.md,
"Files from others")."""
MAX_TORCH_FILE_BYTES = 2 << 30
"""A model file (``.pt``) or training checkpoint is read only up to this size (2 GiB); a larger one is refused
before a byte is read (``learn.model.read_torch_file``). Why: the file was read whole, so a received 10 GB file
filled memory first. Sizes made here (s28-small): the paper net (256-256-128) at 640x480 is 11.2 MB, nearly all
its reference frame (41 bytes a pixel); the weights are 0.42 MB, 6.4 MB for 1024-1024-512 and 135 MB for
4096-4096-4096 (``TrainConfig``'s widest layers). The largest model a user can make, 4096-4096-4096 for a camera of
:data:`MAX_IMAGE_PIXELS`, is 0.82 GB; its checkpoint (weights, two Adam moments, the best weights) 0.54 GB."""
REPEATED_FRAME_DIFFERENCE = 0.01
"""An LED image repeats the one captured before it (a camera whose frames lag the LED switch: the frame read after
switching to LED k was still exposed under LED k-1) when the median over the lit gel of their relative difference,
``|a - b| / max(a, b)`` of their means over blocks of :data:`CAPTURE_CHECK_BLUR` pixels a side, is below this
(:func:`nlipscalib.core.repeated_frames.repeated_leds`). Two neighbouring LEDs of nlipstac differ by 0.10-0.12
(12-bit linear twin; 0.095-0.115 with the block means, s27 lead), 0.055-0.14 after an 8-bit sRGB webcam's tone
curve and auto exposure; the same light captured twice differs by its noise, 0.3 % after a 5x5 box blur (twin,
12-bit; the block means average as many pixels), 0.000 for a frame handed out twice. A twice-as-dense ring
(24 LEDs) would still differ by about 0.05 (linear)."""
LAGGED_BAND_ROWS = 3
"""Fewest rows of blocks (of :data:`CAPTURE_CHECK_BLUR` pixels) at the top or bottom of an LED image (or columns at
its left or right: a camera mounted turned 90 degrees, s30-qaleft) that must show the light of the image captured
before it (within :data:`REPEATED_FRAME_DIFFERENCE`) for the image to be called partly lagged: the LEDs switched
while a rolling shutter read the frame out (:func:`nlipscalib.core.repeated_frames.lagged_bands`). 15 pixels.
Why a run of rows: one row of blocks of two neighbouring LED images can come within 1.6 % (twin presses at 640x480,
/tmp/keep and extra); none came below 1 %, and no run of 3 rows below 3 % reached an image's top or bottom
(s28-rolling); no edge row or column of blocks within 1 % on /tmp/keep and 19 captures at 320x240 (s30-qaleft)."""
LAGGED_BAND_CONTRAST = 2 * REPEATED_FRAME_DIFFERENCE
"""A row (column) of blocks can show an LED image's lag (:func:`nlipscalib.core.repeated_frames.lagged_bands`) only
where the LED images before and after it differ there by at least this (median relative difference over its lit gel
blocks): the image's own light lies between its neighbours', so where they differ by less than twice
:data:`REPEATED_FRAME_DIFFERENCE` its own light and the previous LED's are alike within that threshold and the line
tells nothing. Why: a camera that sees the whole dome down to its base (a wide view, the gel not filling the frame,
s32-rimview) sees at the frame's last gel columns only the far base rim, which neighbouring LEDs of the ring light
alike (0.2-0.6 % apart, the next LED 1.3-3.6 %, 160x120 twin press): 3 such columns were called lagged, "led_08.png's
columns 135-149 (right) show led_07.png's light", and left out of the solve. A true lag band holds the light of an
LED two ring places from the next (nlipstac: 0.2 apart, :data:`REPEATED_FRAME_DIFFERENCE`'s note). Since s33-rimband
the image before the previous one must differ from it there by as much too: where the previous LED is the ring's
brightest (dimmest) at a line, the image's own light is as near it as the image before it is, not between it and
the next (a wide view's far base rim: the LED across the dome lights it least, its neighbours either side alike;
gel two LEDs light only by the indirect light, beyond both terminators). The next image alone was not enough: the
zone where neighbouring LEDs light alike spans more lines of blocks the finer the image, while
:data:`LAGGED_BAND_ROWS` counts lines, so 3-9 such lines were still called a band, "led_08.png's columns 290-309
(right) show led_07.png's light" (undeformed nlipstac_wide, 320x240; with the next image alone 13 of 24 clean wide
captures at 160x120, 320x240 and 640x480, direct light and one bounce, at the frame's sides and bottom: led_02.png's
columns 20-64, led_08.png's 585-619 at 640x480); with both sides none, and a band read before the switch over 3/8 of
the frame still found at each size (benchmarks/RESULTS.md, s33-rimband). With the capture's LED model the two LEDs'
modelled lights must differ there by as much too, and each side's image is the nearest whose LED the model tells
from the previous one at that line: LEDs designed in close pairs light the gel far from the pair alike (every clean
paired capture was warned; a true lag of a pair's first LED mostly unseen, before s35-pairband)."""
LAG_BLIND_SHARE = 0.2
"""Two consecutive LEDs are named as a pair the lag-band check is blind to (:mod:`nlipscalib.core.lag_blind`: one
INFO line, once per command, where the check runs; the solve's report.json ``lag_blind_pairs``) when the LED model
lights the gel so alike from both (within :data:`LAGGED_BAND_CONTRAST`) that a band of the first's light in the
second's frame, read from the frame's edge, can cover this share of the gel's rows or columns, beyond the
:data:`LAGGED_BAND_ROWS` any band needs, and not be found. s35-exchange's designs at 160x120: LEDs in pairs 0.5 mm
apart 0.59-0.76, 0.8 mm 0.41-0.43, 1.2 mm 0.24 (pairs and triples); the shipped designs 0 (nlipstac_wide 0.05-0.12: its
far base rim). A lag of 3/8 of the frame between a pair's LEDs was found on 4 of 16, 20 of 40 and 40 of 40 injections
(s35-pairband); a fifth of the frame unseen is a blind spot worth a word, the wide view's rim is not (s36-lagcost)."""
SHIFTED_BAND_RATIO = 0.7
"""The rows of a band of the frame are read out before the LED switch in every LED image (a systematic timing
error: the camera's rolling readout starts before each LED switches) when, in median over the LEDs, the LED image
fitted (gain and offset) to the previous LED's modelled light leaves less than this fraction of the misfit to its own
LED's (:func:`nlipscalib.solver.led_checks.shifted_rows`). The twin's presses (/tmp/keep, 640x480, 16 bands of 30
rows): 1.18 and above in every band; bands read before the switch: 0.09-0.48 (s28-rolling). Bands of columns alike
(a camera turned 90 degrees; 16 bands of 40 columns at 640): see benchmarks/RESULTS.md, s31-darkall."""
HALF_DARK_NOISE = 3.0
"""A band over more than half an LED's image, looked for on the LED calibration's converged LEDs
(:func:`nlipscalib.solver.calibration_bands.half_dark_bands`), is called dark only when its gel pixels' median light
(linear, the channels' mean) is at most this many times its image's noise: the dark frame's level. Why: against the
converged LEDs of s31-ledfar's twin (LEDs 3 mm / 25 deg off their design, one bounce, 160x120) LEDs 4 and 5 came out
"dark" in columns 75-159 / 0-114 at the light-ratio test alone while their light there was 51 / 40 times the noise; a
band read while the LED was off holds the dark frame's noise (median about 0) (s32-ledleft). The solve's LED check
asks the same of such a band (:func:`nlipscalib.solver.led_checks._half_dark_rows`, s36-lagcost)."""
DARK_BAND_ROWS = 3
"""Fewest bands of :data:`CAPTURE_CHECK_BLUR` rows (columns) in a run, 15 pixels, for an LED image's rows (or every
LED image's) to be called dark at the bands' test: read while no LED was lit; shorter runs are looked at row by row
(:data:`DARK_CANDIDATE_SHARE`, :data:`DARK_LINES_MIN`; every LED image's too since s31-darkall:
:func:`~nlipscalib.core.repeated_frames.dark_everywhere_lines`); :func:`nlipscalib.core.repeated_frames.dark_bands`,
:func:`~nlipscalib.core.repeated_frames.dark_everywhere`. As :data:`LAGGED_BAND_ROWS`."""
DARK_BAND_LIGHT = 0.25
"""Rows are dark (read while no LED was lit, or a very dim LED) when, in :data:`DARK_BAND_SHARE` of a band of
:data:`CAPTURE_CHECK_BLUR` rows' samples, the LED image's light over the light the LED model (albedo fitted over the
LEDs) gives it, relative to its median over the gel, is below this; every LED image at once: their summed light over
its median over the gel, per 5x5 block. The twin (one bounce, 16 spp; /tmp/keep at 640x480 and 24 presses at
320x240, deep ones at the frame's edge): 0.965 and above in every band of every LED, 1.00 and above for the sum;
rows read while no LED was lit 0.00 (s29-darkrows). A synthetic 3 mm dent filling a cropped frame: 0.64. Bands of
columns (a camera turned 90 degrees), the same test: 0.823 and above on /tmp/keep and 18 presses at 320x240, 12 of them
at the frame's left or right side (a 10 mm cylinder 2.5 mm deep over every row: 0.823; s30-darkcols). The LEDs'
summed light pixel row by pixel row (column by column; the 90 % quantile of ~100 gel pixels a line): 0.957 and above
on those captures and 4 more edge presses (s31-darkall)."""
DARK_BAND_SHARE = 0.9
"""Share of a band's samples (or blocks) that must be dark (:data:`DARK_BAND_LIGHT`): a dark band is dark across the
whole row; a contact's flank turned away from an LED is dark in a part of it (a quantile, not the median: the
twin's median over a band goes down to 0.82 on the presses above)."""
DARK_CANDIDATE_SHARE = 0.15
"""A band of :data:`CAPTURE_CHECK_BLUR` rows (columns) of an LED image is looked at pixel row by pixel row when this
share of its samples (two or more) is dark (:data:`DARK_BAND_LIGHT`;
:func:`nlipscalib.core.repeated_frames.dark_candidates`): one dark row in five leaves ~20 % of a band's samples dark
(~4 samples a row at 640x480, ~8 at 320x240). Set low on purpose: the pixel rows' own test decides."""
DARK_LINES_MIN = 2
"""Fewest pixel rows (columns) in a run for a band shorter than :data:`DARK_BAND_ROWS` bands to be called dark, each
with :data:`DARK_BAND_SHARE` of its ~100 samples under :data:`DARK_BAND_LIGHT`
(:func:`nlipscalib.core.repeated_frames.dark_lines`). One row alone is left to the solve's shadow test: a single
line is what a dead sensor row or a transmission glitch gives, not an LED switched against the readout."""
DARK_BAND_MARGIN = 5
"""Pixel rows (columns) either side of an LED image's dark band that the solve leaves out with it, for that LED
(:func:`nlipscalib.core.repeated_frames.dark_band_mask`): the bands of 15 rows or more are found to
:data:`CAPTURE_CHECK_BLUR` rows, and an LED switching during the readout ramps its light over a few rows (a dim
edge that is neither dark nor the LED's light). A lagged band's too (the previous LED's light, found to the block of
:data:`CAPTURE_CHECK_BLUR` rows: the block across the switch holds both lights), with the rows beyond it to the
frame's edge (s31-darkall)."""
LINEAR_RESPONSE_SLOPE = 0.7
"""LED images are taken as not linear in the light (an sRGB or gamma-encoded camera output) when, across the LEDs,
each pixel's value grows as the LED model's light, direct plus the fitted indirect term, to a power below this, in
median over the gel (:func:`nlipscalib.solver.led_checks.recorded_response_slope`). One-bounce twin, 320x240, 16 spp,
undeformed and pressed, two seeds: linear 0.99-1.02 on the default dome (the /tmp/keep 640x480 captures too), the
capsule, the fingertip, the flat and the oblate designs; through the sRGB curve (8 bits) 0.46-0.49. Halfway between,
in ratio. Against the direct light alone (before s28-capslin, limit 0.55) a linear capture's slope was its direct
share: the default dome 0.75, the fingertip 0.56, the capsule 0.28-0.34 (every capsule solve warned)."""
RESPONSE_POWER_LAW_FIT = 0.9
"""``nlips capture`` names a reference's tone curve (:data:`LINEAR_RESPONSE_SLOPE`'s slope below its limit) only where
the LED frames follow a power law of the LED model's light: each pixel's log-log fit across the LEDs with an R^2 of
at least this, in median over the gel. The one-bounce twin's undeformed nlipstac (160x120) as 8-bit frames: linear,
gamma 2.2 and linear plus a 20-of-255 black level 0.998; flat grey frames of a camera of another scene (the device
tests' recorded frames) 0.22, slope 0.06, which named a tone curve where a black level was the fault (s37). Below it,
the capture says nothing of a tone curve (a dark frame above the black level named as one, as before); the solve
asks no fit (its warning as it was)."""
DECLARED_CURVE_SLOPE = 1.2
"""A capture that declares a tone curve (meta.json ``sensor.camera_response`` "srgb") whose LED images, the curve
undone, grow as the LED model's light to a power above this (:data:`LINEAR_RESPONSE_SLOPE`'s slope) is taken as
declared wrongly: its frames were linear already, and undoing a curve they never had bends them the other way.
The default twin (640x480, sphere1): encoded 8-bit sRGB and declared 0.752 (as linear, 0.752); linear but declared
sRGB 1.571, contact AAE 20.0 deg, silent before this check. Halfway between 0.75 and 1.57, in ratio, rounded down.
With the fitted indirect term in the model (s28-capslin) a rightly declared capture gives 1.00-1.02 (default dome,
capsule, fingertip, 320x240); a linear one declared sRGB 1.56 on the default dome (the term fits to 0 on such
frames), but 1.11 on the fingertip and 0.52 on the capsule (their interreflection: not told)."""
JPEG_BLOCKINESS = 1.3
"""LED images are taken as JPEG-compressed (a camera streaming MJPEG, or frames saved as JPEG) when their values
jump more than this many times as much across an 8x8 block grid's edges as inside its blocks
(:func:`nlipscalib.core.compression.blockiness`). Frames never compressed: 1.00-1.01 (the one-bounce twin, 12 and 8
bits, linear and sRGB, 96x72 to 640x480, the /tmp/keep captures included). Through OpenCV's JPEG encoder at
quality 75-95, 8-bit linear: 1.50-1.99; 8-bit sRGB: 1.38-1.88; quality 98 (1.02-1.06) is not told from noise.
30 % above the uncompressed frames, below the weakest compressed (benchmarks/RESULTS.md, s27-webcam2)."""
EXPOSURE_DRIFT = 0.05
"""A press's LED images are taken as exposed unlike the undeformed capture's (auto exposure, gain or white balance
on) when one LED's brightness against the undeformed capture's, per channel, strays from their median by more
than this fraction (:func:`nlipscalib.solver.led_checks.exposure_drift`). The one-bounce twin's presses at one
exposure: within 0.25 % (320x240 and 640x480, 12 and 8 bits); the emulated webcam's auto exposure (+-15 %) and
white balance (+-8 %): 0.78-1.26."""
LED_GAIN_CORRECTION = 0.01
"""A solve against the undeformed capture (``--reference``) rescales an LED's image to that capture's brightness
(:func:`nlipscalib.solver.led_checks.led_gains`) when, after the press's overall gain
(:data:`REFERENCE_GAIN_DRIFT`'s), one LED's brightness against that capture, per channel, strays from 1 by more than
this fraction (LEDs aged on their own, or auto exposure). The one-bounce twin's presses at one exposure: within
0.35 % (per LED and channel; nine 640x480 presses), 0.43 % on large or steep contacts (a 3 mm deep sphere, a 20 mm
coin, 55-70 deg polar presses, two spheres; 320x240); one LED group 5 % dimmer: 0.95 (benchmarks/RESULTS.md,
s28-ledgain). A contact over most of the gel: up to 3 % on the whole gel (the flat pad's 5 mm cube), 0.5 % outside the
solve's box, given or found by ``--roi auto`` (benchmarks/RESULTS.md, s41-flatcube, s41-autogain). A large contact on
the hemisphere (a 30 mm sphere, 16-22 mm flat cylinders over 41-54 % of the gel, 640x480): up to 1.4 % on the whole
gel and 2.5 % outside ``--roi auto``'s box, each its own way (the dent's interreflection; within 0.16 % without
bounces), so ``--roi auto`` rescales only the LEDs both find astray (:func:`~nlipscalib.solver.led_checks.agreed_gains`;
benchmarks/RESULTS.md, s42-autogain2)."""
REFERENCE_GAIN_DRIFT = 0.03
"""A press's LED images are warned of as brighter or dimmer than the undeformed capture's, every LED alike (LEDs aged,
exposure or gain changed), when that gain (:func:`nlipscalib.solver.led_checks.reference_gain`, per channel) strays
from 1 by more than this fraction. The one-bounce twin's presses at one exposure: within 0.25 %; the solve scales the
undeformed capture's light by the gain whatever its size (benchmarks/RESULTS.md, s28-dimref)."""
MODEL_GROUP_GAIN = 0.03
"""Without an undeformed capture (no ``--reference``), a tri-colour LED group
(:func:`nlipscalib.core.leds.tricolor_groups`) is taken as aged (or brightened) on its own when its median light
against the LED model, over the median group's, strays from 1 by more than this fraction
(:func:`nlipscalib.solver.led_checks.model_led_gains`): warned about, and its images rescaled by that group gain.
The twin's design LEDs as captured: within 1.63 % (59 640x480 presses: /tmp/keep, extra, train50); its red group
5 % dimmer: 0.96-0.97 (benchmarks/RESULTS.md, s28-noref)."""
MODEL_LED_GAIN = 0.07
"""Without an undeformed capture, one LED is taken as aged on its own when its light against the LED model, over its
group's median, strays from 1 by more than this fraction (:func:`nlipscalib.solver.led_checks.model_led_gains`): the
model's own error puts single LEDs up to 3.6 % off their group on every press (the twin's design LEDs, the same LEDs
each time), so this is twice that; LED 5 15 % dimmer: 0.87 (benchmarks/RESULTS.md, s28-noref)."""
RESPONSE_MIN_EXPOSURES = 5
"""Fewest exposures a camera-response bracket (``nlips calibrate-camera-response``) has: each code of the curve is
then seen at several light levels even where the gel's light varies little. The emulated one-LED bracket at
sqrt(2) steps sees each code in about five of its exposures."""
RESPONSE_MIN_WELL_EXPOSED = 3
"""Fewest exposures of a bracket whose gel is mostly neither black nor clipped (:data:`RESPONSE_DARK_CODE` to
:data:`RESPONSE_CLIPPED_CODE` on half its pixels): fewer, and the bracket is refused as black or saturated."""
RESPONSE_DARK_CODE = 5
"""8-bit codes at or below this count as black in a bracket frame (read noise around the black level)."""
RESPONSE_CLIPPED_CODE = 250
"""8-bit codes at or above this count as clipped in a bracket frame (a camera's knee before 255)."""
RESPONSE_REACH_LOW = 48
"""A bracket must see some 8-bit code at or below this one, and some at or above :data:`RESPONSE_REACH_HIGH`: the
curve below the lowest code seen is a straight line to black, above the highest a straight line's extrapolation to
white; over longer spans a tone curve's bend is guessed, not measured. The emulated one-LED bracket (0.5-64 ms,
sqrt(2) steps) sees codes 10-17 up to 254."""
RESPONSE_REACH_HIGH = 224
"""See :data:`RESPONSE_REACH_LOW`."""
RESPONSE_MIN_RISE = 0.5
"""Least rise, in 8-bit codes, of a bracket frame's mean over the frame at the next shorter exposure (on the pixels
whose mean code of the two is neither black nor clipped): less, and the two frames are taken as one exposure (a
camera that ignores or quantises the exposure asked, or frames that lag it) and the bracket is refused, as its fit
would assume two exposure times where the camera took one. The emulated brackets' half-stop steps (64x48, 1 spp)
rise by 2.5-54 codes (linear camera), 6.2-30 (gamma 2.2), 5.6-28 (S-curve); two frames of one exposure, other noise
seeds, by under 0.04 (benchmarks/RESULTS.md, s30-bracket)."""
RESPONSE_RISE_PIXELS = 0.01
"""Fraction of a frame's samples that must be neither black nor clipped in a pair of bracket frames for their rise to
be judged (:data:`RESPONSE_MIN_RISE`): fewer (both black, both clipped), the pair says nothing."""
RESPONSE_MAX_DIP = 0.005
"""A fitted response may fall by at most this fraction of full scale from one code to the next (read noise on the
few darkest codes seen: the emulated brackets dip by 0.0005 at most) before it is refused as not monotonic; smaller
dips are flattened (the running maximum)."""
RESPONSE_CHANNEL_SPREAD = 0.015
"""Channels whose fitted curves, each averaged over 15 codes, differ by more than this fraction of full scale
(:func:`nlipscalib.device.response_fit.channel_difference`) each keep their own curve in the response file; closer,
their mean is kept, as for sRGB: a difference within the fit's own error (:data:`RESPONSE_CURVE_ERROR`) is noise.
The emulated sensor's one curve (linear, gamma 2.2, S-curve, sRGB; half and full stops, 64x48 1 spp and 160x120
4 spp) differs by 0.0009-0.0076 between its channels (0.016 code by code, full stops, unaveraged); the emulated
gamma 2.0 / 2.2 / 2.4 camera by 0.067-0.070 (benchmarks/RESULTS.md, s31-respcam)."""
RESPONSE_RATIO_ERROR = 0.025
"""The light of two consecutive bracket frames, the fitted curve undone, may differ from their exposures' ratio by
this fraction before the bracket is refused as taken at other times than asked
(:func:`nlipscalib.device.response_fit.check_exposure_ratios`). The emulated brackets stay within 0.0005-0.0071,
a noisier synthetic one (full stops from 0.125 ms, its darkest frames mostly noise) within 0.019; a stand-in camera
taking one exposure 3 / 4 / 6 % off the asked shows 2.7 / 3.8 / 5.5 % (benchmarks/RESULTS.md, s31-respcam)."""
RESPONSE_RATIO_LOW_CODE = 32
"""Pixels whose merged light puts them below this 8-bit code in the darker frame of a pair are left out of the
pair's ratio (:data:`RESPONSE_RATIO_ERROR`): at the dark end a code's light is a few codes' rounding and noise."""
RESPONSE_ESTIMATE_LOW_CODE = 64
"""Pixels whose merged light puts them below this 8-bit code in the darker frame of a pair are left out of the
pair's ratio when a bracket folder's times are estimated (:mod:`nlipscalib.device.bracket_times`): higher than
:data:`RESPONSE_RATIO_LOW_CODE`, because an estimate is fitted at again and again, and the dark codes' bias (noise
clipped at black) would add up over the rounds (a noisy synthetic right bracket from 0.125 ms: steps 1-4 % off with
32, within 0.9 % with 64; benchmarks/RESULTS.md, s33-bracket)."""
RESPONSE_ESTIMATE_ROUNDS = 4
"""Most rounds of fit and ratio update when a bracket folder's times are estimated
(:mod:`nlipscalib.device.bracket_times`): the emulated 1/n s shutter bracket's steps come within 0.64 % in 3-4
(the curve mostly in 2); more rounds let a right bracket's dark steps drift with their bias (s33-bracket)."""
RESPONSE_ESTIMATE_STEP = 0.015
"""A bracket folder's times estimated from its frames are used instead of those named (said in a line) when a step
between consecutive frames the estimate judges differs from the named step by more than this fraction
(:mod:`nlipscalib.device.bracket_times`). Right brackets' estimates stay within 0.0003-0.0084 of the named steps
(the emulated sensor's four curves, 64x48 1 spp three seeds and 160x120 4 spp: 0.0045 at most; a noisy synthetic
64x48 one, five seeds: 0.0084); a 1/n s shutter table's 4.17 % step is estimated as 3.78-4.19 % (s33-bracket). Within
it the named times are kept: the curve bit for bit as before."""
RESPONSE_BLACK_CODES = 2.0
"""Most 8-bit codes a bracket's dark frame (every LED off, the shortest exposure) may read above the black level
given, its median over the frame, before the bracket is refused as from a camera that adds a black level
(:func:`nlipscalib.device.response_fit.check_black`). Read noise around the right black gives 0 (half the pixels
below black, clipped there); the emulated gamma 2.2 camera's dark frame 0."""
RESPONSE_CURVE_ERROR = 0.015
"""What the emulated tests hold a recovered curve to, fraction of full scale, over codes 10-250: OpenCV's
CalibrateRobertson on the one-LED bracket gives 0.48-0.53 % for gamma 2.2 and sRGB, 0.63 % for the S-shaped
vendor curve (0.77 % over every code; 160x120, 4 spp; benchmarks/RESULTS.md, s30-response); at the tests' 64x48,
1 spp 0.54-0.59 %, the S-shaped 0.58 % (0.74 % over every code; s30-docsqa)."""
RESPONSE_ADDITIVITY_ERROR = 0.015
"""With the fitted camera-response curve undone, two LEDs lit together may give their light lit apart (the dark
frame taken off each) within this fraction (summed over the pixels both light alike, and over those one lights
mostly: :mod:`nlipscalib.device.additivity`); beyond it the curve is raised to the power that makes every pair add
(the exposure times a power of the asked ones), or the calibration refused when none does. The emulated cameras'
right curves add within 0.12-0.43 % (64x48, 1 spp; the stand-in webcam of the tests 0.67 %); times to the power 0.9 /
1.1 miss by 7.9-8.1 / 5.6-6.4 %, 0.97 by 2.5 % (benchmarks/RESULTS.md, s31-additive). Within it, a power a = 0.98
at most goes unseen: its curve ~0.7 % off, the fit's own error."""
RESPONSE_ADDITIVITY_GAP = 0.003
"""Once the curve is raised to the power that makes the LED pairs add (:data:`RESPONSE_ADDITIVITY_ERROR`), a pair's
error where both LEDs light a pixel alike and where one lights it mostly may differ by this fraction: a power of the
curve explains the misfit at every mix, a pair that dims as a whole does not. Emulated cameras whose times are a
power 0.9-1.1 of the asked ones, pinned, leave 0.01-0.23 % (200 runs: five curves, ten noise seeds, 64x48 1 spp;
0.01-0.13 % at 160x120); the stand-in webcam 0.05-0.2 %. Pairs at 0.98 of their light apart leave 0.39-0.59 %
(0.45-0.52 % at 160x120), at 1.02 0.50-0.71 %: s31's 0.6 % let them through (all / 16 of 50) as a power 1.03 /
0.96, the curve 1.3-1.4 % off (benchmarks/RESULTS.md, s31-additive, s32-devleft). A pair dimmed by 1.5 % or less
mostly stays within the 1.5 % of :data:`RESPONSE_ADDITIVITY_ERROR` and the curve is kept as fitted (right: the
bracket is one LED's)."""
RESPONSE_ADDITIVITY_COMMON = 0.006
"""A curve kept as fitted (its LED pairs add within :data:`RESPONSE_ADDITIVITY_ERROR`) whose pairs' errors have a
median beyond this fraction is said in one line, not changed: the pairs dim (or brighten) each other as a whole by
about 1-1.5 %, which the curve (one LED's bracket) does not see, or the times are a power within 0.98-1.02 of the
asked (the curve up to ~0.7 % off); at that size the two cannot be told apart (their bins' gap as fitted 0.00-0.19 %
against 0.21-0.53 %, 64x48). Right cameras: 0.00-0.40 % (the emulated sensor, five curves x six seeds, 64x48 1
spp; the stand-in webcam 0.01 %); pairs at 0.99 of their light apart -0.63 to -1.00 %, at 1.01 +1.00 to +1.42 %,
kept at 0.985 -1.13 to -1.40 % (benchmarks/RESULTS.md, s33-bracket)."""
RESPONSE_ADDITIVITY_POWERS = (0.5, 2.0)
"""The powers of the fitted curve tried to make the LED pairs add (:data:`RESPONSE_ADDITIVITY_ERROR`): times that
are ``t ** a`` of the asked ones give a curve off by the power ``a``; a = 0.5-2 spans shutter tables from a base
of sqrt(2) taken for 2 to 4 taken for 2. A power needed beyond them is no time table: refused."""
LED_GROUP_CHANGE = 0.03
"""``nlips calibrate-leds --previous OLD``: a tri-colour LED group whose median share of the light
(:func:`nlipscalib.core.led_change.led_brightness_ratios`, relative to the median LED) strays from OLD's by more than
this fraction is named as changed (aged together, as on one driver channel). Set from the calibration's repeatability:
the twin's undeformed dome at 160x120, one bounce, 16 spp, seven noise seeds (21 pairs of calibrations): group medians
within 0.25 % (median), 0.9 % (95th percentile), 1.9 % at worst; a group aged to 0.90 reads 0.890-0.914, to 0.95
0.945-0.964 against the seven (4 % missed the 0.964) (benchmarks/RESULTS.md, s32-ledaged)."""
LED_BRIGHTNESS_CHANGE = 0.07
"""... and an LED whose share over its group's median strays by more than this fraction is named on its own (the same
21 pairs: 0.4 % median, 1.7 % 95th percentile, 4.2 % at worst)."""
LED_OVERALL_CHANGE = 0.03
"""... and the light of all LEDs alike (:func:`nlipscalib.core.led_change.overall_brightness_ratio`: the median LED's
ratio of its median over the gel's pixels above the dark frame) straying from OLD's by more than this fraction is
named: every LED aged alike, their drive, or the camera's exposure or gain changed, which the shares above cannot see
(both files gauged to mean Psi = 1). The twin's undeformed dome at 160x120, one bounce, 16 spp, seven noise seeds (42
ordered pairs): within 0.10 % (median), 0.16 % (95th percentile), 0.25 % at worst (the fitted albedo, which also
carries the scale: 3.96 % at worst, as it trades against the coating's reflectance); every LED at 0.90 read
0.898-0.902 against the seven. Kept at the groups' 3 %: a real sensor's LED drive and temperature vary where the
twin's do not (benchmarks/RESULTS.md, s32-prevbright)."""
LED_MOVED_MM = 0.6
"""... and an LED whose calibrated position lies farther than this (mm) from OLD's is named as moved (the same 21
pairs: 0.09 mm median, 0.24 95th percentile, 0.43 at worst; a larger capture repeats closer)."""
LED_TURNED_DEG = 4.0
"""... or whose axis turned by more than this (degrees) (the same pairs: 0.57 deg median, 1.76 95th percentile, 2.64
at worst)."""
LED_EXCHANGE_MM = 1.0
"""``nlips calibrate-leds``: LED images captured in each other's place (the wiring, the controller's LED order or the
images' order) are named when each LED of the exchange was fitted at least this much (mm) nearer another LED's
design place than its own, or less where the other LEDs scatter little (:data:`LED_EXCHANGE_SCATTER`;
:func:`nlipscalib.core.led_exchange.place_exchanges`), and :data:`LED_EXCHANGE_NEARER` times nearer. The twin's
clean calibrations (160x120, one bounce, 16 spp, seven noise seeds): point LEDs 0.19-0.51 mm from their design places
(the best point sits ~0.23 mm behind the disk), 4.55 mm or more from any other; led_03.png and led_04.png exchanged:
4.68 mm from their own, 0.19 / 0.28 mm from each other's (benchmarks/RESULTS.md, s33-ledswap)."""
LED_EXCHANGE_NEARER = 3.0
"""... and at least this many times nearer. Why a ratio too: a sensor built off its design (LEDs 3 mm from their
places, the farthest s31-ledfar starts from) has LEDs up to 1.3 mm nearer a neighbour's place on the default ring
(4.66 mm apart: at best 1.66 mm from it, 1.8 times nearer), never 3 times; on a ring twice as dense (2.3 mm apart) an
LED would have to be built 1.75 mm toward a neighbour's place to reach it."""
LED_EXCHANGE_SCATTER = 5.0
"""... and nearer by at least this many times the other LEDs' median distance from their own places (the common
shift, turn and scale of all LEDs taken out: :func:`nlipscalib.core.led_exchange.exchange_margin`) where that is
under :data:`LED_EXCHANGE_MM`: a calibration that places its LEDs closely tells an exchange of LEDs designed closer
than 1 mm. The twin's clean calibrations (160x120, one bounce, 16 spp; the shipped scenes and scene copies with LEDs
in pairs or triples 0.5-1.2 mm apart, 48 captures): 0.026-0.104 mm median (nlipstac_realistic, built off its design,
0.62-0.73), the worst LED 1.2-4.6 times the median; two LEDs 0.8 mm apart exchanged: 0.65 mm or more nearer each
other's places, against a margin of 0.13-0.23; 0.5 mm apart: 0.41 or more against 0.15-0.36 (the limit). Random fits
and builds 0.02-3 mm off, with a common shift, turn and scale, on rings of 3-36 LEDs and pairs or triples 0.5-1.2 mm
apart: no more cycles named than by 1 mm alone (benchmarks/RESULTS.md, s35-exchange)."""
LED_EXCHANGE_MIN_MM = 0.1
"""... and by at least this much (mm) however closely the others sit (a noise-free fit): the smallest design spacing
an exchange is told at is about twice it."""
LED_ALIGN_MAX_TURN_DEG = 10.0
"""The largest turn (degrees) of the fitted LEDs against their design that :func:`nlipscalib.core.led_exchange.
aligned_places` takes out: a ring built turned by a degree or two moves its LEDs 0.2-0.3 mm along the ring, toward
their neighbours; a half turn would flip a three-LED ring with two exchanged onto its design."""
IMAGE_EXCHANGE_GAIN = 0.1
"""``nlips calibrate-leds`` of several captures: a capture whose LED images correlate at least this much better with
another capture's images of other LEDs than with their own LED's (over the gel) holds them in another order
(:func:`nlipscalib.core.led_exchange.exchanged_images`). The twin's 160x120 undeformed dome, seeds 7 and 8: an LED's
images 0.9987 or more, two neighbours' 0.83 at most; led_03.png and led_04.png exchanged: 0.71 with their own, 0.999
with each other's (gain 0.29; benchmarks/RESULTS.md, s33-ledswap)."""
MODEL_EXCHANGE_FACTOR = 5.0
"""``nlips solve``: LED images exchanged are told against the LED model's light of the undeformed dome when each
image of the cycle correlates better with the LED it shows than with its own by at least this many times the other
images' median misfit to their own LEDs (one minus the correlation; :func:`nlipscalib.core.led_exchange.
exchanged_in_shading`). The twin's presses with two neighbours' images exchanged: 8.1 times or more (the coin press,
640x480, one bounce; 35 on a 320x240 sphere); an LED model 1-4 mm off the sensor, 200 random draws each: 3.8 at
most, where a gain of :data:`IMAGE_EXCHANGE_GAIN` alone named 21-68 cycles of 200 (benchmarks/RESULTS.md,
s34-solveswap)."""
EXCHANGE_OFF_BAND_SHARE = 0.3
"""``nlips solve``: an LED image with a dark band is judged for an exchange with a neighbour's on its samples outside
the band and its margin when they are at least this share of its samples (:func:`nlipscalib.solver.led_checks.
_correlations_off_bands`); below it the dark-band warning says that no exchange could be told there. Bands are found
up to half the frame's rows (columns), leaving 0.36 or more of the samples: the synthetic sphere's led_03.png and
led_04.png exchanged, a band of 10-50 % of either's rows or columns (start, middle, end) told at 0.36-0.80 kept, by 8.7
or more times the others' misfit (:data:`MODEL_EXCHANGE_FACTOR`: 5); the twin's 160x120 presses (three spheres, a
cube), 192 such bands: all told (9.9 times or more), the same bands in clean images none (the gain negative;
benchmarks/RESULTS.md, s35-leftovers)."""
MODEL_EXCHANGE_MIN_GAIN = 0.02
"""... and by at least this much (correlation): a floor under a model that fits the images almost exactly. The
capsule's ring (3.4 mm apart): its least distinct neighbours exchanged gain 0.039 (18 times the others' misfit);
a clean press's images correlate with any other LED's light 0.16 less than with their own."""

GEL_FRAME_SHARE_FOR_DISKS = 0.95
"""A whole-frame solve with point LEDs whose gel covers less of the frame than this (the camera sees past the gel:
the dome's base, black corners) and whose LED file holds fitted disks is told once to solve with ``--led-model
disks`` (:func:`nlipscalib.pipeline.solve.hint_disk_leds`). Why: beside the LEDs the point model misses the light
cups' light by up to 8.5 % and bent the whole gel's depth (the twin's wide view, 84 % gel: contact depth RMSE 0.084
mm with points, 0.003 with disks, s32-rimdepth); the gel-filling default view covers the whole frame (share 1.0)."""

GEL_FRAME_SHARE_PAST_GEL = 0.95
"""A solve whose prior's gel (the reference's finite depth) covers less of the frame than this sees past the gel, and
its smoothness penalises the deformation from the reference (``SolverOptions.smooth_deformation`` "auto"). Why: there
the dome's own curvature, pulled straight by a smoothness of log-depth, put the gel's outer 2-4 px 5-10 deg off (the
twin's wide view, 84 % gel, s33-rimedge); the gel-filling default view covers the whole frame (share 1.0) and keeps
its bits. The share of :data:`GEL_FRAME_SHARE_FOR_DISKS`, the same question."""

CLOSE_PAIR_LIGHT_CORRELATION = 0.95
"""``nlips solve``: two LEDs whose modelled lights of the undeformed dome correlate over the gel by at least this much
are told apart by how their light differs, not by their light (:func:`nlipscalib.solver.led_checks.
_close_pair_exchanges`): LEDs designed 0.8 mm apart correlate 0.990-0.993 (the twin's `pairs08` design), where an
exchange of their images leaves every image correlating with its own LED's light as well as with the other's; the
shipped ring's neighbours (4.7 mm apart) 0.8 at most, told by :data:`MODEL_EXCHANGE_FACTOR` (benchmarks/RESULTS.md,
s37-swapcheck)."""
CLOSE_PAIR_EXCHANGE_CORRELATION = -0.5
"""... and their images are said to be exchanged when the two images' normalised difference ((a - b) / (a + b), the
albedo cancelled) correlates with the LED model's at or below this: +0.89 to +0.95 on the twin's clean `pairs08`
presses and undeformed captures (160x120, 320x240), -0.93 to -0.95 with a pair's two images exchanged; with the LED
model's LEDs each 0.1-0.4 mm off the sensor no clean press is flagged (48 draws) and the exchange is still told
(-0.52 to -0.94); at 0.5 mm, more than half the pairs' spacing, some clean ones are (benchmarks/RESULTS.md,
s37-swapcheck)."""

TRICOLOR_MISFIT = 0.03
"""``nlips solve``: the tri-colour frame does not hold the light of the LED images when a channel's fit to the images
of the LED groups lit in it (each group's images summed, one gain per group and channel, fitted: the camera's colour
response and the tri-colour exposure) misfits by more than this share of the channel, or by more than
:data:`TRICOLOR_NOISE_MARGIN` times the misfit the capture's own noise leaves where that is more (RMS over RMS, of
the frames' means over blocks of 1/60 of the frame's shorter side, 8 px at 640x480, on the gel;
:func:`nlipscalib.core.tricolor_check.tricolor_fit`, :func:`~nlipscalib.core.tricolor_check.tricolor_samples`).
The twin's 640x480 sphere presses, clean, at the noise levels of ``nlips experiment studies`` (full well / read
noise 40000/1, 10000/2 the default, 2500/4, 625/8): 0.001, 0.002, 0.004, 0.008 (on single pixels, as until s40:
0.008, 0.015-0.018, 0.030-0.031, 0.060-0.063: every press of a camera 2x noisier than the twin's was warned); two
images of LEDs of different groups exchanged, at every noise level: 0.040-0.054 (the shipped ring's LEDs 4 and 5, the
weakest of its 32 cross-group pairs; that pair exchanged back fits to the clean misfit), 0.116-0.155 (LEDs 1 and 9);
another 1 mm press's frame 0.027-0.050 (a third of them under it: not told, as on single pixels); sphere1 with cube1's
frame 0.040-0.050. The blocks cut the noise, not these disagreements, which are smooth over the dome
(benchmarks/RESULTS.md, s37-swapcheck, s40-trinoise). The floor for a capture whose noise leaves less than half of
it: a real camera's colour response is not linear to 1 % (unmeasured)."""
TRICOLOR_NOISE_MARGIN = 1.5
"""The tri-colour frame's misfit allowed, as a multiple of the misfit the capture's own noise leaves when that is
more than :data:`TRICOLOR_MISFIT` / this (:func:`nlipscalib.core.tricolor_check.noise_misfits`: the fit's residual
differenced between each block and the mean of its two partner blocks 2 blocks to either side, whose noise is
independent and in which a disagreement linear over the three blocks cancels; until s43 between the two halves of
each block, checkerboards of 2x2 px cells, which a Bayer camera's demosaicing correlated). Why: a fixed 3 % warns
every clean press of a camera whose blocks keep that much noise (a noisier camera, or a smaller frame's smaller
blocks: the twin's 625/8 presses read in 2x2 px blocks, as a 160x120 frame's, misfit ~3 %; on single pixels, as until
s40, its presses at 4x and 16x its noise variance misfit 3.0-3.1 % and 6.0-6.3 %, the 18 that s40's ``nlips
experiment studies`` warned). The measured noise misfit against the clean misfit of the twin's 640x480 presses:
0.92-1.07x at every noise level between each block's halves (s41-tricheck), 0.97-1.03x between blocks and their
partners, and 0.9-1.0x of a Bayer camera's frames, where the halves measured 0.3-0.4x (s43-bayer), so 1.5x leaves a
clean press a third over its own noise; under 2 % of noise (3 % / 1.5) the floor alone decides, as before. Two
images exchanged across groups add their misfit to the noise's (4.0-4.3 % on noiseless images for the shipped ring's
weakest pair, led_04 / led_05): the twin's 625/8 presses in 2x2 px blocks (noise 3.0-3.2 %, allowed 4.6-4.7 %, every
clean one warned at a fixed 3 %) misfit 5.1-5.3 % with it, all named; with noise added until the clean misfit is
2.9-3.2 % (640x480, Gaussian, where bright blocks clip and are left out) it misfit 3.7-4.0 %, under the 4.2-4.6 %
allowed: not told (the fixed 3 % warned 8 of those 9 clean presses). 2x, tried first, lost that pair at 2 % of noise,
where the fixed 3 % still told it without a false alarm (benchmarks/RESULTS.md, s41-tricheck: measured with the
halves)."""
TRICOLOR_GROUPS_APART = 0.02
"""The tri-colour frame is judged only where the LED groups' summed images tell the groups apart: in every channel
the smallest over the largest singular value of the three groups' sums at the gel samples (each scaled to unit
norm) at least this. The twin's dome: 0.18-0.24 (80x60 to 640x480, pressed or not); frames lit evenly (a flat target,
the capture tests' grey frames): 0, any gains fit them, and a verdict there named colours it could not tell
(:func:`nlipscalib.core.tricolor_check.tricolor_note`; s37-tricap)."""

RESET_DARK_FRAME_SHARE = 0.5
"""A stream watching its LED board (``device.live_leds.ResetWatch``: ``nlips live`` / ``nlips infer`` of a camera or
the emulated sensor with ``--port``) asks the board whether it reset when a frame's level (the mean of a subsample)
falls under this share of the last lit frame's: the LEDs dark, the frame holds the black level and any stray light
(the reset tests' camera: 0.024 of a lit frame; the emulated sensor's dark frame is found too, its test), where a
press moves a frame's mean by a few per cent. A wrong call costs one exchange with the board (STATE, 11-20 ms at
115200 on the firmware in simavr), nothing dropped (benchmarks/RESULTS.md, s38-devwatch)."""
