"""Pictures of the race for ``env.render()``.

Frames are drawn by the worker that hosts the env session (the Rust ``paddock-render``
crate, the same renderer as ``paddock rollout --video``) and arrive as packed RGB bytes,
so a local env (``endpoint=None``) and a remote one give the same bytes. This module
turns a reply into arrays and shows frames in a window for ``render_mode="human"``.

The window uses pygame, an optional dependency: ``pip install "paddock[human]"``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.error import DependencyNotInstalled

from . import errors
from ._proto import paddock_pb2 as pb

RENDER_MODES = ["rgb_array", "human"]
DEFAULT_WIDTH = 800  # pixels; 160..2048; the height follows the track's shape
# the widths a server draws (EnvRender.width; 0 on the wire means DEFAULT_WIDTH)
WIDTHS = (160, 2048)


def frames_of(image: pb.EnvImage, rgb: memoryview | bytes, count: int) -> np.ndarray:
    """The ``count`` frames of an image reply (its ``EnvImage`` and pixel frame), shape
    (count, height, width, 3) uint8."""
    shape = (count, int(image.height), int(image.width), 3)
    want = count * image.height * image.width * 3
    if len(rgb) != want:
        raise errors.BadMessage(1, "env_image.rgb",
                                f"rgb has {len(rgb)} bytes, expected {want} for shape {shape}")
    return np.frombuffer(rgb, dtype=np.uint8).reshape(shape)


class Window:
    """A window that shows frames at most ``fps`` times per simulated second of wall time."""

    def __init__(self, fps: float, title: str = "Paddock") -> None:
        try:
            import pygame  # noqa: PLC0415 (optional dependency, imported on first use)
        except ImportError as e:
            raise DependencyNotInstalled(
                'render_mode="human" needs pygame: pip install "paddock[human]"') from e
        self._pg = pygame
        self._fps = float(fps)
        self._title = title
        self._screen: Any = None
        self._clock = pygame.time.Clock()

    def show(self, frame: np.ndarray) -> None:
        pg = self._pg
        h, w = frame.shape[:2]
        if self._screen is None or self._screen.get_size() != (w, h):
            pg.display.init()
            pg.display.set_caption(self._title)
            self._screen = pg.display.set_mode((w, h))
        # pygame surfaces index (x, y): transpose the (row, column) frame
        surface = pg.surfarray.make_surface(np.ascontiguousarray(frame.transpose(1, 0, 2)))
        self._screen.blit(surface, (0, 0))
        pg.event.pump()
        pg.display.flip()
        self._clock.tick(self._fps)

    def close(self) -> None:
        if self._screen is not None:
            self._pg.display.quit()
            self._screen = None
