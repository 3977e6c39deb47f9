# aar-dock service: FastAPI (port 8000) + viser 3-D scene (port 8080) + simulated docking stream.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    AAR_HOST=0.0.0.0 \
    AAR_PORT=8000 \
    AAR_VISER_PORT=8080 \
    AAR_RECORDINGS_DIR=/data/recordings \
    NUMBA_CACHE_DIR=/opt/numba-cache

WORKDIR /app
RUN useradd --create-home --uid 10001 aar && mkdir -p /data/recordings && chown aar /data/recordings

# runtime dependencies only (no [dev] extra). The page, the paper's calibration and the sample
# pairs ship inside the package (app/_data links to static/ and sample_data/): copy them first.
COPY pyproject.toml README.md ./
COPY static ./static
COPY sample_data ./sample_data
COPY app ./app
RUN pip install . && rm -rf build /app/app /app/static /app/sample_data
# compile the navigation core's loops into the image (numba's cache; the service user may
# add to it if it runs on another CPU model)
RUN mkdir -p /opt/numba-cache && python -m app.sim.warmup && chown -R aar /opt/numba-cache
WORKDIR /data

USER aar
EXPOSE 8000 8080
VOLUME ["/data/recordings"]
HEALTHCHECK --interval=15s --timeout=5s --start-period=90s --retries=3 \
  CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/api/v1/healthz', timeout=4).status == 200 else 1)"]
CMD ["aar-dock", "serve"]
