"""The results pages in a real browser: headless Chromium (Debian's chromium and chromium-driver)
driven by Selenium, against a real `airpuff serve` on a loopback port with a real Dask worker and
a token.  A small coarse sweep is submitted through the form and followed until it is done (the
page refreshes itself); the figures must load as PNG; a bad value must show the same message as
POST /sweeps beside its field; text from the request must stay text.

Screenshots of every page go to ``$AIRPUFF_SCREENSHOT_DIR`` if set (else the test's tmp folder).
Without a browser on the machine the module is skipped with one line saying why.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path
from urllib.parse import quote

import httpx
import pytest
import xarray as xr

from tests.api.support import ServerProcess

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
try:
    import selenium  # noqa: F401
except ImportError:  # pragma: no cover - the test extra installs it
    selenium = None

if not (CHROMIUM and CHROMEDRIVER and selenium):
    pytest.skip("browser test skipped: "
                + ("selenium is not installed (pip install -e '.[test]')" if selenium is None else
                   "no chromium/chromedriver on this machine (apt-get install chromium "
                   "chromium-driver; .ci/run does it)"), allow_module_level=True)

from selenium import webdriver  # noqa: E402
from selenium.common.exceptions import (  # noqa: E402
    JavascriptException,
    StaleElementReferenceException,
    WebDriverException,
)
from selenium.webdriver.common.by import By  # noqa: E402
from selenium.webdriver.support import expected_conditions  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

pytestmark = [pytest.mark.service, pytest.mark.cluster, pytest.mark.browser]

TOKEN = "page&test=token+/%42"  # characters that need URL encoding in the form
# A coarse sweep whose runs are short but still applanate twice: the jet peaks at 7 ms and the
# runs end at 15 ms, after the second applanation (about 10 ms).
FORM = {"E0": "0.3, 0.6", "IOP": "12:20:3", "thickness": "0.5", "pmax": "10",
        "T": "12", "t0": "7", "t_end": "15"}
N_POINTS = 6


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with ServerProcess(tmp_path_factory.mktemp("pages") / "data", "--workers", "2",
                       token=TOKEN).running(wait_runner=True) as s:
        yield s


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    out = os.environ.get("AIRPUFF_SCREENSHOT_DIR")
    path = Path(out) if out else tmp_path_factory.mktemp("screenshots")
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture(scope="module")
def browser():
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1280,900", "--lang=en-GB"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(options=opts, service=webdriver.ChromeService(CHROMEDRIVER))
    driver.set_page_load_timeout(120)
    try:
        yield driver
    finally:
        driver.quit()


def screenshot(driver, path: Path) -> None:
    """The whole page (the window grown to the page's height), as PNG."""
    height = driver.execute_script("return document.documentElement.scrollHeight")
    driver.set_window_size(1280, min(max(height + 150, 600), 6000))
    driver.save_screenshot(str(path))
    driver.set_window_size(1280, 900)
    assert path.stat().st_size > 1000


def session_client(server, driver) -> httpx.Client:
    """An HTTP client holding the browser's cookies (and no bearer header)."""
    cookies = {c["name"]: c["value"] for c in driver.get_cookies()}
    return httpx.Client(base_url=server.url, cookies=cookies, timeout=60)


def job_status(driver) -> str:
    """The status shown on a job's page, read in one script call: the page reloads itself while
    the job runs, which would make a found element stale before its text is read."""
    return (driver.execute_script(
        "var e = document.getElementById('status'); return e ? e.textContent : '';") or "").strip()


def click_and_wait(driver, button_id: str) -> None:
    """Click a submit button and wait for the next page (a click does not wait for it)."""
    old_page = driver.find_element(By.TAG_NAME, "html")
    driver.find_element(By.ID, button_id).click()
    # Asked about the old page while the next one replaces it, Chrome may answer "Node with given
    # id does not belong to the document" (a WebDriverException) instead of a stale element: ask
    # again until the old page is reported stale.
    WebDriverWait(driver, 60, ignored_exceptions=(WebDriverException,)).until(
        expected_conditions.staleness_of(old_page))


def login(driver, token: str) -> None:
    box = driver.find_element(By.ID, "f-token")
    box.clear()
    box.send_keys(token)
    click_and_wait(driver, "login")


def open_page(driver, server, path: str) -> None:
    """Open ``path``, logging in first if the server asks for the token."""
    driver.get(server.url + path)
    if "/login" in driver.current_url:
        login(driver, TOKEN)


def test_token_flow(server, browser, shots):
    """Nothing is served without the token; the login form sets a cookie that opens the pages and
    the API's read-only endpoints, but not the API's POST."""
    with httpx.Client(base_url=server.url, timeout=30) as anon:
        for path in ("/", "/new", "/jobs/abc", "/jobs/abc/figures/ora-P1.png"):
            r = anon.get(path)
            assert r.status_code == 303 and r.headers["location"].startswith("/login?next="), path
        assert anon.get("/sweeps").status_code == 401
        assert anon.post("/new", data=FORM).status_code == 303  # to the login form, no job
    with server.client() as api:
        assert api.get("/sweeps").json()["total"] == 0

    browser.get(server.url + "/new")
    assert "/login" in browser.current_url
    screenshot(browser, shots / "login.png")
    login(browser, "wrong")
    assert browser.find_element(By.ID, "login-error").text == "wrong token"
    login(browser, TOKEN)
    WebDriverWait(browser, 30).until(lambda d: d.current_url.endswith("/new"))
    cookie = browser.get_cookie("airpuff_session")
    assert cookie["httpOnly"] and cookie["sameSite"] == "Strict" and TOKEN not in cookie["value"]
    with session_client(server, browser) as c:
        assert c.get("/").status_code == 200
        assert c.get("/sweeps").status_code == 200  # the API's GET accepts the cookie
        r = c.post("/sweeps", json={"resolution": "coarse"})  # its POST does not
        assert r.status_code == 401


def test_bad_value_shows_the_api_message(server, browser, shots):
    """A value out of range gets the message POST /sweeps gives, beside its field; the other
    fields keep what was typed; markup typed into a field stays text."""
    with server.client() as api:
        expected = api.post("/sweeps", json={"E0": [0.3, -1.0]}).json()["detail"]
    assert [d["field"] for d in expected] == ["E0"]
    open_page(browser, server, "/new")
    fields = {"E0": "0.3, -1", "IOP": '12"><script>window.injected=1</script>'}
    for name, text in fields.items():
        box = browser.find_element(By.ID, f"f-{name}")
        box.clear()
        box.send_keys(text)
    click_and_wait(browser, "submit")
    WebDriverWait(browser, 30).until(lambda d: d.find_elements(By.ID, "error-E0"))
    assert browser.find_element(By.ID, "error-E0").text == expected[0]["msg"]
    assert "invalid" in browser.find_element(By.ID, "f-E0").get_attribute("class")
    # the markup came back as the field's value, not as a script
    assert browser.find_element(By.ID, "f-IOP").get_attribute("value") == fields["IOP"]
    assert browser.execute_script("return window.injected === undefined")
    assert "IOP" in browser.find_element(By.ID, "error-IOP").text
    screenshot(browser, shots / "form-error.png")
    with server.client() as api:
        assert api.get("/sweeps").json()["total"] == 0  # nothing was submitted

    # a job id from the URL is shown escaped on the 404 page
    browser.get(server.url + "/jobs/" + quote("<b id=injected>x"))
    assert "No such job" in browser.page_source
    assert not browser.find_elements(By.ID, "injected")


def test_submit_follow_and_plots(server, browser, shots):
    """Submit through the form, watch the page refresh itself until the job is done, then check
    the table against the metrics JSON and the netCDF, and that every figure loads as a PNG that
    is drawn once and kept."""
    open_page(browser, server, "/new")
    screenshot(browser, shots / "form.png")
    browser.find_element(By.TAG_NAME, "summary").click()  # open the model options
    for name, text in FORM.items():
        box = browser.find_element(By.ID, f"f-{name}")
        box.clear()
        box.send_keys(text)
    click_and_wait(browser, "submit")
    WebDriverWait(browser, 30).until(lambda d: "/jobs/" in d.current_url)
    job_id = browser.current_url.rsplit("/", 1)[1]
    if job_status(browser) in ("queued", "running"):
        screenshot(browser, shots / "job-running.png")

    # The page reloads itself while the job runs (nothing here reloads it).
    WebDriverWait(browser, 600, poll_frequency=1,
                  ignored_exceptions=(JavascriptException, StaleElementReferenceException)).until(
        lambda d: job_status(d) in ("done", "failed", "cancelled"))
    assert job_status(browser) == "done"
    assert f"{N_POINTS} / {N_POINTS} done, 0 failed" in browser.find_element(By.ID, "progress").text

    with server.client() as api:
        metrics = api.get(f"/sweeps/{job_id}/metrics").json()
        request = api.get(f"/sweeps/{job_id}").json()["request"]
    assert request["E0"] == [0.3, 0.6] and request["IOP"] == [12.0, 16.0, 20.0]
    assert request["t_end"] == 15.0 and request["resolution"] == "coarse"
    points = metrics["points"]
    assert len(points) == N_POINTS and all(p["status"] == "ok" for p in points)
    # both applanations happen within 15 ms, so every ORA metric exists
    for p in points:
        assert all(p[m] is not None for m in ("P1", "P2", "CH", "IOPg", "IOPcc", "DA")), p

    # the metrics table shows each point's P1 as the JSON has it (4 significant digits)
    rows = browser.find_elements(By.CSS_SELECTOR, "#metrics + div table tbody tr")
    assert len(rows) == N_POINTS
    p1_column = 1 + 4 + 1  # '#', the four axes, status
    for row, p in zip(rows, points):
        cells = row.find_elements(By.TAG_NAME, "td")
        assert cells[p1_column].text == f"{p['P1']:.4g}"
        # beside it the calibrated P1: none for these options, and the page says why
        assert p["P1_cal"] is None and cells[p1_column + 1].text == "\u2013"
    header = browser.find_elements(By.CSS_SELECTOR, "#metrics + div table thead th")
    assert header[p1_column + 1].text == "P1_cal [mmHg]"
    status_text = browser.find_element(By.ID, "calibration-status").text
    assert points[0]["calibration_missing"] in status_text
    assert "make one with: airpuff calibrate --instrument paper" in status_text

    # every figure has loaded in the browser and is a PNG over HTTP
    images = browser.find_elements(By.CSS_SELECTOR, ".figures img")
    names = [img.get_attribute("src").rsplit("/", 1)[1] for img in images]
    assert sorted(names) == sorted(["ora-P1.png", "ora-P2.png", "ora-CH.png", "ora-IOPg.png",
                                    "ora-IOPcc.png", "heatmap-DA.png", "heatmap-CH.png",
                                    "history-0.png"])
    WebDriverWait(browser, 180).until(lambda d: all(d.execute_script(
        "return arguments[0].complete && arguments[0].naturalWidth > 0", img) for img in images))
    figures_dir = server.data_dir / "jobs" / job_id / "figures"
    with session_client(server, browser) as c:
        for img in images:
            r = c.get(img.get_attribute("src"))
            assert r.status_code == 200 and r.headers["content-type"] == "image/png"
            assert r.content.startswith(b"\x89PNG\r\n\x1a\n") and len(r.content) > 5000
        # drawn once: the cached files are served again, not redrawn.  Besides the figures shown
        # now, the cache may hold the history of another point: while the job ran, the page
        # showed the history of the first point finished then, which need not be point 0
        cached = {p.name: p.stat().st_mtime_ns for p in figures_dir.glob("*.png")}
        assert set(names) <= set(cached), cached
        assert all(re.fullmatch(r"history-[1-9]\d*\.png", n) for n in set(cached) - set(names)), \
            cached
        time.sleep(0.05)
        for name in names:
            assert c.get(f"/jobs/{job_id}/figures/{name}").status_code == 200
        assert {p.name: p.stat().st_mtime_ns for p in figures_dir.glob("*.png")} == cached

        # the links of the page work with the browser's cookie
        assert c.get(browser.find_element(By.ID, "metrics-link").get_attribute("href")
                     ).json()["points"] == points
        r = c.get(browser.find_element(By.ID, "dataset-link").get_attribute("href"))
        assert r.status_code == 200 and r.headers["content-type"] == "application/x-netcdf"
    nc = server.data_dir.parent / "page-dataset.nc"
    nc.write_bytes(r.content)
    with xr.open_dataset(nc) as ds:
        for p in points:
            value = float(ds["P1"].sel(E0=p["E0"], IOP=p["IOP"], thickness=p["thickness"],
                                       pmax=p["pmax"]))
            assert value == pytest.approx(p["P1"], rel=1e-12)
    screenshot(browser, shots / "job.png")

    # another point's history, chosen from the table
    rows[3].find_element(By.TAG_NAME, "a").click()
    WebDriverWait(browser, 30).until(lambda d: "point=3" in d.current_url)
    img = browser.find_element(By.CSS_SELECTOR, "img[src$='history-3.png']")
    WebDriverWait(browser, 180).until(lambda d: d.execute_script(
        "return arguments[0].complete && arguments[0].naturalWidth > 0", img))

    browser.get(server.url + "/")
    row = browser.find_element(By.CSS_SELECTOR, f"a[href='/jobs/{job_id}']")
    assert row.text == job_id[:8]
    assert f"{N_POINTS} / {N_POINTS} done" in browser.page_source
    screenshot(browser, shots / "jobs.png")
