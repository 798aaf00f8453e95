"""Scene generator: analytic primitives ray traced in OpenCL into sample buffers and
converged references."""
from clrecon.scenes.builtin import SCENES, get_scene
from clrecon.scenes.primitives import Box, Material, Plane, Quad, Scene, Sphere
from clrecon.scenes.render import render_reference, render_samples

__all__ = ["SCENES", "get_scene", "Box", "Material", "Plane", "Quad", "Scene", "Sphere",
           "render_reference", "render_samples"]
