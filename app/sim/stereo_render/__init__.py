"""Synthetic stereo images of the drogue's LED ring with exact ground truth (paper §3–5).

* :mod:`~app.sim.stereo_render.scene` — the settings, the ground truth, the rendered pair;
* :mod:`~app.sim.stereo_render.blobs` — one emitting sphere's disc and anti-aliased patch;
* :mod:`~app.sim.stereo_render.patch_kernels` — the compiled loops: a blob's patch and its
  compositing into the image (and the tracker's windows);
* :mod:`~app.sim.stereo_render.distractors` — clutter and the hostile extras (glints,
  reflections on the rim);
* :mod:`~app.sim.stereo_render.sensor` — background, sensor noise, compositing, windows;
* :mod:`~app.sim.stereo_render.renderer` — :func:`render_pair`, the pair renderer.
"""

from app.sim.stereo_render.renderer import render_pair
from app.sim.stereo_render.scene import LED_BGR, RenderedPair, RenderSettings, RenderTruth

__all__ = ["LED_BGR", "RenderSettings", "RenderTruth", "RenderedPair", "render_pair"]
