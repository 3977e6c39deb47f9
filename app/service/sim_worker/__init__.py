"""The docking simulation in a persistent worker process that keeps the tick schedule.

Rendering the 1280×1024 pair and running the pipeline take 5–20 ms of CPU per tick at 30 Hz;
in the web server's process they would share its GIL with request handling. One worker
process (``spawn`` context) builds and steps the :class:`app.sim.docking.DockingSimulation`
*and keeps the fixed-rate schedule itself*: the web server's process is not in the loop's
critical path (its tick thread shares the GIL with the WebSocket clients, the uploads' HTTP
work and the 3-D scene; see ``docs/service.md``).

The package, by side of the process boundary:

* child side (imports nothing of ``app.service`` outside this package, so the worker stays
  light): :mod:`.wire` (the messages on the pipe, the calibration as a dict),
  :mod:`.image_ring` (camera images in shared memory), :mod:`.priority` (the CPU priority a
  thread asks for), :mod:`.worker` (the worker's main loop and its schedule);
* parent side: :mod:`.proxy` (:class:`~.proxy.SimWorker`, the paced source
  :class:`~.proxy.ProcessSimSource`, :func:`~.proxy.process_source_factory` and the launcher
  that starts the worker, :class:`~.proxy.SpawnLauncher`).

This is the simulation's one execution path: tests inject a launcher that runs the same worker
loop (:class:`~.worker.WorkerLoop`) in their process (``tests/support/inline_sim.py``).

This ``__init__`` imports nothing, so that importing the child side does not load the parent's.
"""
