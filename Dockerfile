# RBA Studio web app: `docker compose up` (see docker-compose.yml); data/ and models/ are mounted, not baked in.
FROM python:3.11-slim-bookworm

# Mesa's EGL renders MuJoCo clips off-screen on the CPU; imageio-ffmpeg brings its own ffmpeg.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libegl1 libegl-mesa0 libgl1 libgl1-mesa-dri libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MUJOCO_GL=egl HF_HUB_OFFLINE=1 \
    RBA_HOST=0.0.0.0 RBA_PORT=8000 RBA_DATA_DIR=/app/data RBA_MODELS_DIR=/app/models

WORKDIR /app
# torch first and pinned, as in the README (pass --build-arg PIP_INDEX_URL=... for a CPU-only index).
ARG PIP_INDEX_URL
RUN python -m pip install --no-cache-dir "torch==2.13.0"
COPY pyproject.toml README.md ./
COPY rba ./rba
COPY server ./server
COPY frontend ./frontend
# Editable, like a checkout: the app finds frontend/ (and default data/, models/) beside its packages.
RUN python -m pip install --no-cache-dir -e . && mkdir -p /app/data /app/models

EXPOSE 8000
VOLUME ["/app/data", "/app/models"]
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"
CMD ["rba", "serve"]
