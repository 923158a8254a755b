"""Real servers for the farm tests: an S3-compatible server (moto's server mode, an HTTP server
on 127.0.0.1) and a Dask ``LocalCluster`` (2 worker processes); small generated models.

Used by tests/test_farm.py, tests/test_remote_cache.py and benchmarks/farm.py.
"""

from __future__ import annotations

import hashlib
import io
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from gltf_builder import GltfBuilder

BUCKET = "assetpipe-farm"
S3_ENV = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class S3Server:
    """moto's S3 server (``moto_server``, its own process) on 127.0.0.1:<free port>, with one
    bucket; ``env`` points botocore at it (also set in os.environ until :meth:`stop`)."""

    def __init__(self):
        import boto3

        self.port = free_port()
        exe = Path(sys.executable).with_name("moto_server")
        cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "moto.server"]
        self.proc = subprocess.Popen(cmd + ["-H", "127.0.0.1", "-p", str(self.port)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.endpoint = f"http://127.0.0.1:{self.port}"
        self.env = {**S3_ENV, "AWS_ENDPOINT_URL": self.endpoint}
        self._old = {k: os.environ.get(k) for k in self.env}
        os.environ.update(self.env)
        self.s3 = boto3.client("s3", endpoint_url=self.endpoint, region_name="us-east-1")
        deadline = time.monotonic() + 60
        while True:
            try:
                self.s3.create_bucket(Bucket=BUCKET)
                break
            except Exception:  # noqa: BLE001 - not listening yet
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(f"moto_server did not start on port {self.port}") from None
                time.sleep(0.2)

    def url(self, prefix: str) -> str:
        return f"s3://{BUCKET}/{prefix}"

    def keys(self, prefix: str) -> list[str]:
        out = []
        for page in self.s3.get_paginator("list_objects_v2").paginate(Bucket=BUCKET, Prefix=prefix):
            out.extend(o["Key"] for o in page.get("Contents", []))
        return out

    def get(self, key: str) -> bytes:
        return self.s3.get_object(Bucket=BUCKET, Key=key)["Body"].read()

    def put(self, key: str, data: bytes) -> None:
        self.s3.put_object(Bucket=BUCKET, Key=key, Body=data)

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        for k, v in self._old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def make_cluster(workers: int = 2):
    """A real Dask cluster: ``workers`` worker processes of 1 thread each, on 127.0.0.1. The scheduler's
    HTTP server (which ``dashboard_address=None`` does not turn off: it then takes 8787) listens
    on a free port, so that two clusters, or another program on 8787, do not collide."""
    from distributed import LocalCluster

    return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                        dashboard_address="127.0.0.1:0")


def make_model(folder: Path, name: str, n: int, seed: int, texture: int = 64) -> Path:
    """A wavy n x n grid (2(n-1)^2 triangles) with UVs and a seeded noise PNG base colour."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    h = 0.1 * np.sin(6 * u + seed) * np.cos(5 * v) + 0.01 * rng.standard_normal(u.shape)
    pos = np.stack([u, h, v], axis=-1).reshape(-1, 3).astype(np.float32)
    uv = np.stack([u, v], axis=-1).reshape(-1, 2).astype(np.float32)
    q = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).reshape(-1)
    idx = np.stack([q, q + n, q + 1, q + 1, q + n, q + n + 1], axis=1).reshape(-1).astype(np.uint32)
    img = (rng.random((texture, texture, 3)) * 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    (folder / f"{name}.png").write_bytes(buf.getvalue())
    b = GltfBuilder()
    prim = {"attributes": {"POSITION": b.add_accessor(pos), "TEXCOORD_0": b.add_accessor(uv)},
            "indices": b.add_accessor(idx), "material": 0}
    b.add_material(name=f"{name}-mat", pbrMetallicRoughness={"baseColorTexture": {"index": b.add_texture(uri=f"{name}.png")}})
    b.add_node(mesh=b.add_mesh([prim]))
    return b.write_gltf(folder / f"{name}.gltf")


def tree(out: Path) -> dict[str, str]:
    """OUT-relative path -> sha256 of every built file (the build's own state folder aside)."""
    return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(out).rglob("*")) if p.is_file() and ".assetpipe" not in p.relative_to(out).parts}
