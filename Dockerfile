FROM python:3.11-slim
WORKDIR /app
COPY pyproject.toml README.md alembic.ini ./
COPY server ./server
COPY client_sim ./client_sim
COPY migrations ./migrations
RUN pip install --no-cache-dir -e .
# compile the particle filter's kernels into the image (numba's disk cache)
RUN python -c "from server.positioning import kernels; kernels.warm_up()"
EXPOSE 8000
CMD ["indoorpos", "serve", "--host", "0.0.0.0", "--port", "8000"]
