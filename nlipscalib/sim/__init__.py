"""The digital twin: parametric domes, indenters, elastomer indentation, Mitsuba 3 rendering.

Produces captures in the core format (nlipscalib.core.capture) with per-pixel ground truth.
Mitsuba is imported only when something renders. ``press.render_press(scene, press, out)`` renders one press folder
(``scene.load_scene``, ``indent.PressConfig``, ``indenters.IndenterConfig``); ``dataset`` a dataset spec's presses.
"""
