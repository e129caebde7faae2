FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md alembic.ini ./
COPY server ./server
COPY migrations ./migrations
# the service only: the research harness (lab/) and the simulator (client_sim/) are
# distributions of their own
RUN pip install --no-cache-dir -e .
# compile the particle filter's kernels into the image (numba's disk cache)
RUN python -c "from server.positioning.filters import particle_kernels; particle_kernels.warm_up()"
EXPOSE 8000
CMD ["indoorpos", "serve", "--host", "0.0.0.0", "--port", "8000"]
