"""The console in a real headless Chromium (Debian's), driven by Playwright: map, camera, deadman driving."""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from fleetslam.middleware import Context
from fleetslam.station.server import STATIC_DIR, StationServer

from ..support import wait_until
from .conftest import RobotUnderTest

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--no-first-run", "--disable-dev-shm-usage", "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
]  # fmt: skip


@pytest.fixture
def browser_page(tmp_path: Path):  # type: ignore[no-untyped-def]
    playwright_api = pytest.importorskip("playwright.sync_api")
    if not Path(CHROMIUM).exists():
        pytest.skip("Debian's chromium is not installed (scripts/setup installs it as root)")
    if not (STATIC_DIR / "vendor" / "three.module.js").is_file():
        pytest.skip("front-end dependencies missing: run scripts/setup-frontend")
    with playwright_api.sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"), executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS,
            viewport={"width": 1400, "height": 820},
        )  # fmt: skip
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        yield page, errors
        context.close()


def _save_screenshot(page, tmp_path: Path, name: str) -> Path:  # type: ignore[no-untyped-def]
    path = tmp_path / name
    page.screenshot(path=str(path))
    artifacts = os.environ.get("FLEETSLAM_ARTIFACTS")
    if artifacts:
        Path(artifacts).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(artifacts) / name)
    return path


def test_console_in_chromium(
    browser_page,
    make_context: Callable[..., Context],
    test_robot: RobotUnderTest,
    tmp_path: Path,  # type: ignore[no-untyped-def]
) -> None:
    page, errors = browser_page
    with StationServer(make_context(), port=0) as server:
        page.goto(server.url)
        page.wait_for_function("window.fleetslam && window.fleetslam.voxelCount > 0", timeout=20000)
        first_frame = page.evaluate("window.fleetslam.lastFrameSeq")
        page.wait_for_function(f"window.fleetslam.lastFrameSeq > {first_frame}", timeout=10000)
        assert page.evaluate("window.fleetslam.selected") == "c3po"
        # Hold the deadman (Space) and W: forward commands reach the robot.
        page.keyboard.down("Space")
        page.keyboard.down("w")
        assert wait_until(lambda: any(v > 0 for _, v, _ in test_robot.commands), 5.0)
        time.sleep(0.5)
        _save_screenshot(page, tmp_path, "console-driving.png")
        page.keyboard.up("w")
        page.keyboard.up("Space")
        released = time.monotonic()
        assert wait_until(lambda: any(v == 0.0 and t >= released - 0.1 for t, v, _ in test_robot.commands), 2.0)
        time.sleep(0.6)
        assert not [c for c in test_robot.commands if c[0] > released + 0.5 and c[1] != 0.0]
        # Close the page while driving: the stream stops.
        page.keyboard.down("Space")
        page.keyboard.down("w")
        assert wait_until(lambda: any(v > 0 and t > released + 0.6 for t, v, _ in test_robot.commands), 5.0)
        page.close()
        closed = time.monotonic()
        time.sleep(1.0)
        assert not [c for c in test_robot.commands if c[0] > closed + 0.5 and c[1] != 0.0]
    assert not errors, errors
