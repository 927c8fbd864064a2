"""The dashboard in a real headless browser (Debian's chromium driven by Selenium).

Loads the page, enters a token, sees the fleet table worst first, opens a component (HI and RUL
charts with alert marks), acknowledges an alert, and checks that ids holding HTML and terminal
escape sequences are shown as text, never run. A screenshot is saved in the test's tmp dir.
"""

import os
import shutil
import tempfile

import numpy as np
import pandas as pd
import pytest

CHROMIUM = next((p for p in ("/usr/bin/chromium", "/usr/bin/chromium-browser")
                 if os.path.exists(p)), None)
CHROMEDRIVER = shutil.which("chromedriver") or (
    "/usr/bin/chromedriver" if os.path.exists("/usr/bin/chromedriver") else None)

EVIL = ['<img src=x onerror="window.__pwned=1">', "<script>window.__pwned=2</script>",
        "\x1b[2J\x1b[31mALARM\x1b]0;title\x07\nforged"]


def _driver(user_dir):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--disable-background-networking", "--disable-component-update", "--disable-sync",
              "--no-first-run", "--disable-extensions", f"--user-data-dir={user_dir}",
              "--window-size=1280,1400"):
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)


def test_dashboard_in_headless_chromium(tmp_path, live_server, need):
    if CHROMIUM is None or CHROMEDRIVER is None:
        need("chromium/chromedriver not installed: apt-get install chromium chromium-driver")
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    from rulkit.fleet.service.app import create_app
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.store.sqlite import ROW_FIELDS

    sdb = ServiceDB(tmp_path / "fleet.db")
    _, token = sdb.create_token("write", "browser")
    t = np.arange(0.0, 120.0)
    frames = [pd.DataFrame({"component": "gearbox-7", "time": t, "hi": 0.3 * np.exp(0.012 * t)})]
    frames.append(pd.DataFrame({"component": "pump-1", "time": t[:30], "hi": 0.2}))
    res = sdb.ingest(pd.concat(frames), source="test")
    assert [a["level"] for a in res["alerts"]] == ["warning", "alarm"]
    # hostile ids written straight into the tables (whatever ingestion accepts, the page
    # must show what the database holds as text): a component row and an open alert each
    cols = ", ".join((*ROW_FIELDS, "max_level"))
    with sdb.store() as s, s._transaction("IMMEDIATE") as conn:
        for name in EVIL:
            conn.execute(f"INSERT INTO components (component, {cols}) SELECT ?, {cols} "
                         "FROM components WHERE component = 'pump-1'", (name,))
        conn.execute("INSERT INTO alerts (component, t, level, previous, valid, raised) "
                     "VALUES (?, 1.0, 1, 0, 1, 0.0)", (EVIL[1],))
    user_dir = tempfile.mkdtemp(prefix="rulkit-chromium-")
    driver = None
    try:
        with live_server(create_app(sdb)) as srv:
            driver = _driver(user_dir)
            wait = WebDriverWait(driver, 20)
            driver.get(srv.url + "/")
            driver.find_element(By.ID, "token").send_keys(token)
            driver.find_element(By.CSS_SELECTOR, "#token-form button").click()
            wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#fleet-table tbody tr"))
                       == 5)
            rows = driver.find_elements(By.CSS_SELECTOR, "#fleet-table tbody tr")
            first = rows[0].find_elements(By.TAG_NAME, "td")
            assert first[0].text == "gearbox-7" and first[1].text == "alarm"
            names = [r.find_element(By.CSS_SELECTOR, "button").text for r in rows]
            # HTML shown as text; control characters shown as visible escapes
            assert EVIL[0] in names and EVIL[1] in names
            assert "\\x1b[2J\\x1b[31mALARM\\x1b]0;title\\x07\\x0aforged" in names
            assert driver.execute_script("return window.__pwned === undefined")
            assert len(driver.find_elements(By.TAG_NAME, "img")) == 0
            assert len(driver.find_elements(By.TAG_NAME, "script")) == 1  # app.js only
            # open a component: HI and RUL charts with two alert marks each
            rows[0].find_element(By.CSS_SELECTOR, "button").click()
            wait.until(ec.visibility_of_element_located((By.ID, "detail")))
            wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#hi-chart circle")) == 120)
            assert driver.find_element(By.ID, "detail-name").text == "gearbox-7"
            assert len(driver.find_elements(By.CSS_SELECTOR, "#hi-chart .alert-mark")) == 2
            assert len(driver.find_elements(By.CSS_SELECTOR, "#rul-chart polygon.band")) == 1
            # acknowledge the alarm
            alarm = next(a for a in res["alerts"] if a["level"] == "alarm")
            alert_rows = driver.find_elements(By.CSS_SELECTOR, "#alert-table tbody tr")
            assert len(alert_rows) == 3
            assert EVIL[1] in [r.find_elements(By.TAG_NAME, "td")[1].text for r in alert_rows]
            driver.find_element(By.ID, "ack-by").send_keys("night shift")
            driver.find_element(By.ID, "ack-reason").send_keys("gearbox swapped")
            driver.find_element(
                By.CSS_SELECTOR, f'#alert-table tr[data-alert-id="{alarm["id"]}"] button.ack'
            ).click()
            wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#alert-table tbody tr"))
                       == 2)
            assert "acknowledged" in driver.find_element(By.ID, "status").text
            shot = tmp_path / "dashboard.png"
            assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000
            logs = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
            assert logs == [], logs
    finally:
        if driver is not None:
            driver.quit()
        shutil.rmtree(user_dir, ignore_errors=True)
    total, done = sdb.alerts(state="acknowledged", component=None, limit=10, offset=0)
    assert total == 1 and done[0]["acknowledged"]["by"] == "night shift"
    assert done[0]["acknowledged"]["reason"] == "gearbox swapped"
    sdb.close()


@pytest.fixture(autouse=True)
def _print_screenshot_dir(tmp_path):
    yield
    shot = tmp_path / "dashboard.png"
    if shot.exists():
        print(f"dashboard screenshot: {shot}")
