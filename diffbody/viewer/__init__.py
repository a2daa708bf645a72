"""Looking at results: the interactive 3D viewer (`view`: the sphere body, a time slider,
overlays and joint angles in the browser or a notebook, served by viser) and animations
(`animate`: every frame drawn to .mp4 or .gif with imageio); ``pip install 'diffbody[view]'``."""

from ._animate import animate as animate
from ._scene import Scene as Scene
from ._scene import build_scene as build_scene
from ._viewer import Viewer as Viewer
from ._viewer import view as view
