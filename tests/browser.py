"""A real browser for the web tests and bench/web.py: Debian's headless Chromium driven by
selenium, WebGL2 on SwiftShader (no GPU needed), pages on loopback only.

``Browser.frame()`` returns the 3D canvas as float RGB in [0, 1]; ``wait_for_scene`` polls
until the canvas shows splats and has stopped changing (viser sorts the splats in a worker,
so the first frames can be partial).
"""

from __future__ import annotations

import io
import shutil
import time
from collections.abc import Callable, Iterator

import numpy as np
from PIL import Image

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


def chromium_missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    for path in (CHROMIUM, CHROMEDRIVER):
        if shutil.which(path) is None:
            return f"{path} is missing: run `make setup` (scripts/install-apt.sh installs it)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is missing: pip install -e '.[dev]'"
    return None


def module_browser(width: int, height: int) -> Iterator[Browser]:
    """A browser for one test module's fixture, closed after it. A missing browser fails the
    test: `make setup` installs it, so its absence is no reason to skip."""
    import pytest  # the tests' alone: bench/web.py opens its Browser itself

    missing = chromium_missing()
    if missing:
        pytest.fail(missing)
    b = Browser(width, height)
    yield b
    b.close()


class Browser:
    """Headless Chromium with a ``width`` × ``height`` window at device-pixel ratio 1."""

    def __init__(self, width: int = 1280, height: int = 720) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for arg in (
            "--headless=new",
            "--no-sandbox",  # CI containers run as root
            "--disable-dev-shm-usage",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",  # WebGL2 on the CPU: no GPU in CI
            "--ignore-gpu-blocklist",
            "--force-device-scale-factor=1",
            f"--window-size={width},{height}",
        ):
            options.add_argument(arg)
        self.driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
        # --window-size sets the outer window; make the page's viewport exactly width × height.
        inner = self.driver.execute_script("return [window.innerWidth, window.innerHeight];")
        self.driver.set_window_size(2 * width - inner[0], 2 * height - inner[1])

    def open(self, url: str) -> None:
        self.driver.get(url)

    def canvas_rect(self) -> tuple[int, int, int, int]:
        """(x, y, width, height) of the largest canvas on the page: the 3D view."""
        rects = self.driver.execute_script(
            "return Array.from(document.querySelectorAll('canvas')).map(c => {"
            "const r = c.getBoundingClientRect(); return [r.x, r.y, r.width, r.height];});"
        )
        if not rects:
            return (0, 0, 0, 0)
        x, y, w, h = max(rects, key=lambda r: r[2] * r[3])
        return (round(x), round(y), round(w), round(h))

    def frame(self) -> np.ndarray:
        """The 3D canvas as it is on screen, (H, W, 3) float32 in [0, 1]; an empty array when
        the page's renderer is too busy to answer within chromedriver's 10 s (SwiftShader
        drawing a large scene on loaded cores): the wait loops then simply try again."""
        from selenium.common.exceptions import TimeoutException

        try:
            return self._frame()
        except TimeoutException:
            return np.zeros((0, 0, 3), np.float32)

    def _frame(self) -> np.ndarray:
        # Hide the page's panels and notifications for the shot, keep the canvases.
        self.driver.execute_script(
            "const s = document.createElement('style'); s.id = 'pano4d-shot';"
            "s.textContent = 'body * {visibility: hidden !important}"
            " canvas {visibility: visible !important}';"
            "document.head.appendChild(s);"
        )
        try:
            png = self.driver.get_screenshot_as_png()
        finally:
            self.driver.execute_script("document.getElementById('pano4d-shot').remove();")
        page = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float32) / 255
        x, y, w, h = self.canvas_rect()
        return page[y : y + h, x : x + w]

    def wait_for_scene(
        self, shown: Callable[[np.ndarray], bool], timeout: float = 120.0, settle: float = 0.5
    ) -> np.ndarray:
        """The first canvas for which ``shown`` holds and that a screenshot ``settle`` seconds
        later repeats (the splat sort has finished); raises TimeoutError after ``timeout``."""
        deadline = time.monotonic() + timeout
        previous: np.ndarray | None = None
        while time.monotonic() < deadline:
            current = self.frame()
            if (
                current.size
                and shown(current)
                and previous is not None
                and previous.shape == current.shape
                and float(np.abs(previous - current).max()) < 2 / 255
            ):
                return current
            previous = current if current.size and shown(current) else None
            time.sleep(settle)
        raise TimeoutError(f"the scene did not appear within {timeout} s")

    def close(self) -> None:
        self.driver.quit()


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR (dB) of two float images in [0, 1], over ``mask`` (H, W) if given."""
    err = (a - b) ** 2
    mse = float(err[mask].mean() if mask is not None else err.mean())
    return float("inf") if mse == 0 else 10 * np.log10(1 / mse)
