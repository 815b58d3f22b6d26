"""Headless Chromium showing the status page, with everything that would reach beyond loopback off.

One place that starts the browser for the tests (``tests/service/test_http_live.py``) and the
benchmarks (``scripts/bench_live.py --with-page``): the distribution's ``chromium`` driven through its
``chromedriver`` with selenium (the ``test`` extra).  By default Chromium talks to the network on its
own — component and safe-browsing updates, sync, translate, metrics, proxy auto-detection, DNS
prefetching — so it is started with :data:`CHROMIUM_FLAGS`, which switch those services off, and with
host resolution limited to ``localhost`` (any other host name fails at once, without a DNS query).

Its profile and temporary files go to a folder of its own, removed by ``quit()``.  The folder is a
short one in the system's temporary directory: Chromium puts its singleton socket there, and a Unix
socket's path may not exceed 107 bytes (a test's ``tmp_path`` under pytest-xdist is longer: the browser
then exits at start).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from typing import Any

#: Flags of every Chromium this project starts.  ``--no-sandbox``: Chromium refuses to run as root with
#: its sandbox (CI runs as root, containers often lack the user namespaces it needs otherwise);
#: ``--disable-dev-shm-usage``: containers' /dev/shm is small; the rest keeps the browser off the
#: network: no background services, no component updater, no sync, no default apps, no first-run
#: tasks, no proxy auto-detection, no DNS look-ups but for ``localhost``.
CHROMIUM_FLAGS: tuple[str, ...] = (
    "--headless=new",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-domain-reliability",
    "--disable-breakpad",
    "--disable-client-side-phishing-detection",
    "--disable-features=Translate,OptimizationHints,MediaRouter,DialMediaRouteProvider,AutofillServerCommunication",
    "--metrics-recording-only",
    "--no-pings",
    "--no-proxy-server",
    "--dns-prefetch-disable",
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, EXCLUDE 127.0.0.1",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
)


class BrowserUnavailable(RuntimeError):
    """selenium, ``chromium`` or ``chromedriver`` is missing; the message says what to install."""


def find_chromium() -> tuple[str, str]:
    """(browser, driver) paths of the distribution's Chromium and chromedriver, or BrowserUnavailable."""
    browser = next((p for p in map(shutil.which, ("chromium", "chromium-browser")) if p), None)
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        raise BrowserUnavailable("no Chromium/chromedriver on this machine (Debian/Ubuntu: apt-get install "
                                 "chromium chromium-driver; .ci/run installs them)")
    return browser, driver


def start_chromium(*extra_args: str, scratch_prefix: str = "mavahrs-chromium-") -> Any:
    """A selenium ``webdriver.Chrome`` on headless Chromium with :data:`CHROMIUM_FLAGS` and ``extra_args``
    (e.g. ``--window-size=1100,800``); BrowserUnavailable when selenium, Chromium or its driver is missing.

    ``quit()`` stops the browser and removes its profile and temporary files.
    """
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError as exc:
        raise BrowserUnavailable("selenium is not installed (pip install 'mavahrs[test]')") from exc
    browser_path, driver_path = find_chromium()
    options = webdriver.ChromeOptions()
    options.binary_location = browser_path
    scratch = tempfile.mkdtemp(prefix=scratch_prefix)
    for arg in (*CHROMIUM_FLAGS, *extra_args, f"--user-data-dir={scratch}/profile"):
        options.add_argument(arg)
    # Chromium's own org.chromium.* scratch folders follow TMPDIR; selenium's usage statistics off
    env = dict(os.environ, TMPDIR=scratch, SE_AVOID_STATS="true")
    try:
        page = webdriver.Chrome(service=Service(driver_path, env=env), options=options)
    except BaseException:
        shutil.rmtree(scratch, ignore_errors=True)
        raise
    quit_page = page.quit

    def quit_and_clean() -> None:
        try:
            quit_page()
        finally:
            shutil.rmtree(scratch, ignore_errors=True)

    page.quit = quit_and_clean
    return page
