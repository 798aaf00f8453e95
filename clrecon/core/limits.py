"""The value limits of a frame of samples: what :meth:`SampleBuffer.validate
<clrecon.core.samples.SampleBuffer.validate>` (host) and :mod:`clrecon.core.inspect`
(device) accept, and the depth of a miss. One definition for the library, the kernels'
``#define`` counterparts and the NumPy references (re-exported by
:mod:`clrecon.core.samples`).

Value bounds (:meth:`SampleBuffer.validate` on the host, :mod:`clrecon.core.inspect` on the
device, same rules and messages), chosen so that no kernel overflows float32 on a valid
frame:

* colour: every channel finite and in ``[0, COLOR_MAX]``, ``COLOR_MAX = 1e30`` (compared
  as float32), so that float32 holds a sum of 3.4e8 colours at the bound. The kernels only
  add colours times weights (none squares a colour), and their largest sums are far below
  that: box's S per pixel, sweep's 49 S per window, splat's layer images and pyramid (~5x
  the largest colour), layered's filtered grids (~1.6e3x at 512x512 16 spp, proportional to
  spp): safe beyond 1e5 spp. ``allow_negative=True`` accepts ``[-COLOR_MAX, COLOR_MAX]``;
  every method then gives ``f(c+) - f(c-)`` (see :func:`clrecon.core.pipeline.run`).
* depth: ``>= MIN_DEPTH = 1e-20`` (float32) or a miss; ``1 / depth <= 1e20`` then fits
  float32 for the methods that place samples in 1/depth (layered buckets, splat layers).
* CoC: the coefficients ``|c1| <= COC_MAX = 2**20`` px (the CoC of a miss) and
  ``|c0| <= COC_MAX * 1e30``, and every hit's ``|coc(depth)| <= COC_MAX`` (about a million
  pixels, wider than any frame: a larger CoC would only spread a sample evenly over it; a
  sample at the near plane of a defocused camera, ~5e5 px, is valid). A CoC square
  (layered's statistics) is then at most 2**40 per sample.
* motion: each component in ``[-MOTION_MAX, MOTION_MAX]``, ``MOTION_MAX = 2**16`` px (a
  length of at most 2**16.5 px, wider than any frame); it bounds splat's motion
  sub-segments (``ceil(|motion| / 192)`` <= 483 per sample).
"""
from __future__ import annotations

#: depths at or beyond this are misses (background)
MISS_DEPTH = 1e30

LENS_TOLERANCE = 1e-4
POSITION_TOLERANCE = 1e-4

#: largest colour magnitude (float32(1e30)); negative colours need ``allow_negative``
COLOR_MAX = 1e30
#: smallest depth of a hit (float32(1e-20))
MIN_DEPTH = 1e-20
#: largest |coc| of a sample and |c1| of the model, pixels
COC_MAX = 2.0**20
#: largest |c0| of the model (pixels times depth units): COC_MAX at the miss depth
C0_MAX = COC_MAX * MISS_DEPTH
#: largest |component| of a motion vector, pixels
MOTION_MAX = 2.0**16
