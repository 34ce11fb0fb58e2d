"""Small dataset specs shared by tests (32x24 images, 1 spp: CI-sized)."""

TINY_SPEC = """
scene = "nlipstac"
seed = 1
[render]
spp = 1
bounces = 0
[camera]
width = 32
height = 24
[grid]
indenters = [{ kind = "sphere", size = 4.0 }]
polar_deg = [0.0, 15.0]
depth = [0.5, 1.0]
"""
