"""The domain model at the bottom of the package: the records every layer speaks, with no
behaviour of their own. Imports nothing of ``app`` but :mod:`app.types` (and no library but
numpy and pydantic); viz, control, sim, streams and the service import it downward.

* :mod:`app.model.tick` — the tick record (:class:`~app.model.tick.TickRecord`) and its parts:
  one published step of any producer, the one shape of the telemetry WebSocket, the history,
  the recordings and the MCAP ``/telemetry`` channel;
* :mod:`app.model.pose` — the navigation pipeline's result (:class:`~app.model.pose.PoseResult`:
  the LEDs, the drogue, the stage timings), the shape the CLI and ``POST /stereo`` return;
* :mod:`app.model.frames` — a camera stream's stereo pair (:class:`~app.model.frames.StereoFrame`)
  and the raw side of a published tick (:class:`~app.model.frames.RawFrame`);
* :mod:`app.model.mount` — the rig's mounting on the receiver
  (:class:`~app.model.mount.CameraMount`; computed by :func:`app.sim.rig_mount.default_mount`);
* :mod:`app.model.drogue` — the guidance's nominal model of the drogue's swing and the bow wave
  (:class:`~app.model.drogue.DrogueModel`).
"""
