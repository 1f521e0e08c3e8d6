# RBA Studio: one image for the web app, the rba commands and the Ray head and workers (docker-compose.yml).
# data/ and models/ are mounted, not baked in.
FROM python:3.11-slim-bookworm

# Mesa's EGL renders MuJoCo clips off-screen on the CPU; imageio-ffmpeg brings its own ffmpeg.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MUJOCO_GL=egl HF_HUB_OFFLINE=1 RAY_USAGE_STATS_ENABLED=0 \
    RBA_HOST=0.0.0.0 RBA_PORT=8000 RBA_DATA_DIR=/app/data RBA_MODELS_DIR=/app/models

WORKDIR /app
# torch first and pinned, as in the README (pass --build-arg PIP_INDEX_URL=... for a CPU-only index); then Ray,
# pinned like the cluster: every node and driver must run the same Ray and Python. Both before the code, so a
# code change does not reinstall them.
ARG PIP_INDEX_URL
RUN python -m pip install --no-cache-dir "torch==2.13.0"
RUN python -m pip install --no-cache-dir "ray==2.60.0"
COPY pyproject.toml README.md ./
COPY rba ./rba
COPY server ./server
COPY frontend ./frontend
COPY deploy/entrypoint.sh ./deploy/entrypoint.sh
# Editable, like a checkout: the app finds frontend/ (and default data/, models/) beside its packages.
RUN python -m pip install --no-cache-dir -e . && mkdir -p /app/data /app/models && chmod 0755 deploy/entrypoint.sh

EXPOSE 8000
VOLUME ["/app/data", "/app/models"]
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"
# The entrypoint joins a Ray cluster first when RAY_HEAD_ADDRESS names one (a Ray driver must run on a node), then
# runs the command; without it, `docker run rba-studio` is plain `rba serve`.
ENTRYPOINT ["/app/deploy/entrypoint.sh"]
CMD ["rba", "serve"]
