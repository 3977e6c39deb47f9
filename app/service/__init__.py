"""The framework-free runtime: the producers (simulation worker, stream runner, upload
executor), the tick loop and telemetry bus, the recorder and the outputs (MCAP, Foxglove,
MAVLink). Nothing here imports FastAPI, Starlette or uvicorn, nor :mod:`app.server`."""
