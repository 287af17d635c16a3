# syntax=docker/dockerfile:1
# impactcell: the API service (default command), and with another command the dask scheduler
# and workers of docker-compose.yml, which import worker.simulate from this same image.
#
#   docker build -t impactcell .
#   docker run --rm -p 8000:8000 -v impactcell-data:/data impactcell
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore

# The package, non-editable, with the PostgreSQL driver. numpy, scipy, numba, netCDF4 and
# psycopg[binary] all ship manylinux wheels, so no compiler is needed; the source tree is built
# in a scratch directory and removed, so only site-packages holds the code and the shipped
# studies (package data: `impactcell run quick`, `impactcell studies`, the nightly suite).
COPY pyproject.toml README.md constraints.txt /tmp/src/
COPY worker /tmp/src/worker
COPY service /tmp/src/service
COPY studies /tmp/src/studies
RUN pip install -c /tmp/src/constraints.txt "/tmp/src[postgres]" \
    && rm -rf /tmp/src \
    && impactcell --help > /dev/null \
    && impactcell studies > /dev/null

# An unprivileged user owning the data dir and numba's cache (site-packages is read-only to it,
# so numba's cache=True kernels need a cache directory of their own).
RUN groupadd --system --gid 10001 impactcell \
    && useradd --system --uid 10001 --gid impactcell --create-home --home-dir /home/impactcell \
        --shell /usr/sbin/nologin impactcell \
    && mkdir -p /app /data /home/impactcell/.cache/numba \
    && chown -R impactcell:impactcell /app /data /home/impactcell

ENV IMPACTCELL_DATA_DIR=/data \
    NUMBA_CACHE_DIR=/home/impactcell/.cache/numba

USER impactcell:impactcell
WORKDIR /app
# Compile every method's numba kernels once, into the image's cache: API, scheduler and workers
# start with compiled kernels instead of each compiling the same ones (about a minute).
RUN impactcell warmup
VOLUME ["/data"]
EXPOSE 8000

CMD ["impactcell", "serve", "--host", "0.0.0.0", "--port", "8000"]
