"""Canonical fixtures, kept in one place (STYLE.md, "Tests").

A unit cube block, one block wholly inside the design prism, one protruding,
one colliding pair and an empty layout, on the built-in ``mini`` scene.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from geometry.blocks import Block, get_block
from geometry.pose import Pose
from geometry.scene import Scene, load_scene

ROOT = Path(__file__).resolve().parents[1]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--screenshots", default=None, metavar="DIR",
                     help="Copy the browser tests' screenshots to DIR (make screenshots: docs/).")


@pytest.fixture
def keep_screenshot(request: pytest.FixtureRequest):
    """``keep(path)``: copy a screenshot a test took in its temporary folder to ``--screenshots``.

    Tests write only to temporary folders; this copy happens only when a
    maintainer asks for it (``make screenshots``).
    """
    folder = request.config.getoption("--screenshots")

    def keep(path: Path) -> None:
        if folder is not None:
            shutil.copyfile(path, Path(folder) / path.name)

    return keep


@pytest.fixture(autouse=True, scope="session")
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Keep CoACD decompositions made by tests out of the user's cache."""
    os.environ["SHOHA_CACHE"] = str(tmp_path_factory.mktemp("shoha-cache"))


@pytest.fixture(scope="session")
def mini() -> Scene:
    return load_scene("mini")


@pytest.fixture(scope="session")
def shake() -> Block:
    return get_block("shake-4t")


@pytest.fixture(scope="session")
def cube() -> Block:
    return get_block("box:1x1x1")


def export_turned(block: Block, path: Path) -> Path:
    """Write ``block``'s mesh turned by an arbitrary rotation and moved off its centroid, as a
    user's file may come (Euler xyz 37, -121, 68 degrees; 0.71, -1.3, 2.45 m)."""
    from scipy.spatial.transform import Rotation

    mesh = block.trimesh.copy()
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [37.0, -121.0, 68.0], degrees=True).as_matrix()
    pose[:3, 3] = [0.71, -1.3, 2.45]
    mesh.apply_transform(pose)
    mesh.export(path)
    return path


def standing(block: Block, x: float, y: float, yaw: float = 0.0, ground: float = 0.0) -> Pose:
    """``block`` standing in its block-frame orientation, turned by ``yaw``, on z = ground."""
    q = np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])
    pose = Pose([x, y, 0.0], q)
    zmin = pose.apply(block.vertices)[:, 2].min()
    return Pose([x, y, ground - zmin], q)


@pytest.fixture(scope="session")
def inside_block(shake: Block) -> tuple[int, Block, Pose]:
    """A Shake Block standing wholly inside mini's design prism."""
    return (0, shake, standing(shake, 0.0, 6.0))


@pytest.fixture(scope="session")
def protruding_block(shake: Block) -> tuple[int, Block, Pose]:
    """A Shake Block standing on the crest, sticking up out of both prisms."""
    return (1, shake, standing(shake, 0.0, 3.0, ground=2.5))


@pytest.fixture(scope="session")
def colliding_pair(cube: Block) -> list[tuple[int, Block, Pose]]:
    """Two unit cubes overlapping by 0.2 m along x, inside mini."""
    return [(0, cube, Pose([0.0, 5.0, 0.5], [1, 0, 0, 0])), (1, cube, Pose([0.8, 5.0, 0.5], [1, 0, 0, 0]))]


@pytest.fixture
def empty_layout() -> list[tuple[int, Block, Pose]]:
    return []


def shoha(*args: str, cwd: Path | None = None, timeout: float = 300,
          env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Run the installed ``shoha`` console script, as a user would."""
    exe = shutil.which("shoha", path=str(Path(sys.executable).parent)) or "shoha"
    return subprocess.run([exe, *args], capture_output=True, text=True, cwd=cwd, timeout=timeout, env=env)


class Served:
    """``shoha serve`` running in a subprocess, as a user starts it; ``url`` once it answers.

    ``args`` are the command-line arguments after ``serve``; the port is
    chosen free and given with ``--port``. The process is stopped (SIGTERM,
    then SIGKILL) when the ``with`` block ends, and its stderr is kept in
    ``log`` for messages.
    """

    def __init__(self, *args: str, timeout: float = 60.0, env: dict[str, str] | None = None):
        import socket

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = int(s.getsockname()[1])
        self.args = [*args, "--port", str(self.port)]
        self.url = f"http://127.0.0.1:{self.port}"
        self.timeout = timeout
        self.env = {**os.environ, **(env or {})}
        self.log = ""

    def __enter__(self) -> Served:
        import time

        import httpx

        exe = shutil.which("shoha", path=str(Path(sys.executable).parent)) or "shoha"
        self.proc = subprocess.Popen([exe, "serve", *self.args], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True, env=self.env)
        deadline = time.monotonic() + self.timeout
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self.log = self.proc.stderr.read()
                raise RuntimeError(f"shoha serve exited {self.proc.returncode}: {self.log}")
            try:
                if httpx.get(self.url + "/healthz", headers=headers, timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.__exit__()
        raise RuntimeError(f"shoha serve did not answer within {self.timeout} s")

    @property
    def token(self) -> str | None:
        return self.args[self.args.index("--token") + 1] if "--token" in self.args else None

    def alive(self) -> bool:
        return self.proc.poll() is None

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log = self.proc.stderr.read() if self.proc.stderr else ""
