# One image for every railswitch service: simulator, diagnoser, recorder, replay, watch.
FROM python:3.11-slim

# A C compiler lets CasADi compile the diagnosis model to machine code (much faster fits).
RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml README.md __init__.py __main__.py ./
COPY models models
COPY schemas schemas
COPY services services
RUN pip install --no-cache-dir ".[postgres]"

# Compiled diagnosis models are cached here; a volume keeps them across restarts.
ENV RAILSWITCH_CACHE=/cache
RUN useradd --create-home railswitch && mkdir -p /cache /data && chown railswitch /cache /data
USER railswitch
ENTRYPOINT ["railswitch"]
CMD ["--help"]
