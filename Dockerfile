# shsas service image. CPU by default; the GPU worker image is the same file with
#   docker build --build-arg VARIANT=cuda -t shsas:cuda .
# (CUDA wheels of torch bring their own CUDA runtime; the host needs only the NVIDIA driver and
# the NVIDIA container toolkit.)
ARG PYTHON=3.11

# The operator console: built from web/ with the lockfile's versions; only the bundle is kept.
FROM node:20-slim AS console
WORKDIR /src/web
COPY web/package.json web/package-lock.json ./
RUN npm ci --ignore-scripts --no-audit --no-fund
COPY web/ ./
RUN npm run build

FROM python:${PYTHON}-slim AS base

ARG VARIANT=cpu
ARG TORCH_VERSION=2.13.0
ARG CUDA_INDEX=https://download.pytorch.org/whl/cu128
ARG CPU_INDEX=https://download.pytorch.org/whl/cpu

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    SHSAS_DATA_DIR=/data \
    SHSAS_CACHE_DIR=/opt/shsas-cache

# gcc + libc headers: the CPU hash-encoding kernel (shsas_core/neural/fields/hashgrid_cpu.c) is built
# with them below; without them CPU training falls back to ~2x slower PyTorch ops.
RUN apt-get update \
    && apt-get install -y --no-install-recommends libgl1 libglib2.0-0 curl gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*

# torch first, from the index that matches the variant, so the resolver never swaps it.
RUN if [ "$VARIANT" = "cuda" ]; then idx="$CUDA_INDEX"; else idx="$CPU_INDEX"; fi \
    && pip install --index-url "$idx" "torch==${TORCH_VERSION}"

WORKDIR /app
COPY pyproject.toml README.md ./
COPY shsas_core ./shsas_core
COPY jobs ./jobs
COPY service ./service
COPY --from=console /src/service/console/static ./service/console/static
COPY worker ./worker
RUN pip install ".[service,fast]"
# build the C kernel once into the image (read-only at run time; the user below can load it)
RUN python -c "from shsas_core.neural.fields import native; assert native.available(), native._state"

# Celery refuses to run as root with some serializers and it is good hygiene anyway.
RUN useradd --create-home --uid 10001 shsas && mkdir -p /data && chown shsas /data
USER shsas
VOLUME ["/data"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=20s \
    CMD curl -fsS http://127.0.0.1:8000/healthz || exit 1

# Default: the one-command embedded service. Compose/Kubernetes override the command for
# `shsas worker` containers and set SHSAS_BROKER_URL / SHSAS_DATABASE_URL.
CMD ["shsas", "serve", "--host", "0.0.0.0", "--port", "8000"]
