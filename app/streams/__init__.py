"""Live stereo streams: frame sources, pairing, push protocol, raw-frame recordings, guidance.

Pure package (numpy + OpenCV; no web imports). A *frame source* yields timestamped stereo pairs
(:class:`~app.streams.frames.StereoFrame`); :func:`~app.streams.sources.open_source` builds one
from a spec string:

* ``video:LEFT,RIGHT`` — two video files, two image folders or two globs (OpenCV
  ``VideoCapture`` / ``imread``), or ``video:DIR`` for a raw-frame recording (``*.frames``);
* ``camera:I,J`` — two capture devices (or two files, for tests), ``camera:I`` with
  ``split`` for one side-by-side stereo device;
* ``push`` — pairs sent over the network (:mod:`app.streams.protocol`), newest kept.

:class:`~app.streams.processor.StreamProcessor` runs everything after the source: the
windowed stereo tracker, the drogue filter and the guidance numbers
(:mod:`app.streams.guidance`).
"""
