"""The dashboard in a real headless browser (Debian's chromium driven by Selenium).

On a pump fleet (ages in hours, exponential HI growth with additive noise; one pump failed,
one stale, one not estimated yet): the counts per level, the sort by RUL and by due date, the
RUL as median [low, high] with its unit and due date, the staleness, a component's charts
(measured and filtered HI, failure threshold, the HI forecast to it with its band and the
RUL interval, axes titled with units and dates; the RUL history with its band), alerts whose
RUL is the table's, and an acknowledgement. Every element is checked as drawn, not by
pixels: through the DOM, the charting library's legend and each chart's data-chart record
of what it drew (points per series, tick labels), against the API's history. The browser
must report no Content-Security-Policy violation. Two screenshots are saved in the test's
tmp dir, and into the directory named by RULKIT_DOCS_SCREENSHOTS when set (how
docs/img/dashboard-*.png are made). Then ids holding HTML and terminal escape sequences are
shown as text, never run. The vendored charting library's files are the ones whose hashes
its README and the page record.
"""

import base64
import hashlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

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
              "--window-size=1400,1500", "--hide-scrollbars"):
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)


def pump_fleet(sdb, now):
    """12 pumps, an acquisition every 12 h: HI = h0 exp(r t) + N(0, 0.02), at ages that put
    them anywhere from healthy to near failure. P-108 crossed HI = 1; P-111's feed stopped 5
    days ago; P-112 was installed 36 h ago (3 acquisitions: no RUL yet)."""
    rng = np.random.default_rng(11)
    frames = []
    for i in range(11):
        t = np.arange(0.0, 12.0 * rng.integers(30, 70), 12.0)
        h0, last = rng.uniform(0.08, 0.12), (1.08 if i == 7 else rng.uniform(0.3, 0.85))
        hi = h0 * np.exp(np.log(last / h0) * t / t[-1]) + rng.normal(0, 0.02, t.size)
        frames.append(pd.DataFrame({"component": f"P-{101 + i}", "time": t,
                                    "hi": np.clip(hi, 0.0, 5.0)}))
    sdb.ingest(pd.concat(frames[:10]), source="feed", now=now)
    sdb.ingest(frames[10], source="feed", now=now - 5 * 86400)
    sdb.ingest(pd.DataFrame({"component": "P-112", "time": [0.0, 12.0, 24.0],
                             "hi": [0.1, 0.11, 0.1]}), source="feed", now=now)


def js_fmt(v):
    """The page's fmt(v, 3) (3 significant digits, exponential beyond [1e-3, 1e5), "∞" for an
    unbounded quantile), written again here."""
    if v is None:
        return "∞"
    a = abs(v)
    if a != 0 and (a >= 1e5 or a < 1e-3):
        m, e = f"{v:.2e}".split("e")
        return f"{m}e{int(e):+d}"
    x = float(f"{v:.3g}")
    return str(int(x)) if x == int(x) else repr(x)


CSP_LISTENER = """window.__csp = [];
document.addEventListener("securitypolicyviolation",
                          (e) => window.__csp.push(e.effectiveDirective));"""
VENDOR = Path(__file__).parents[3] / "src/rulkit/fleet/service/static/vendor"


def rows_of(driver, by):
    return driver.find_elements(by.CSS_SELECTOR, "#fleet-table tbody tr")


def names_of(driver):
    """The fleet table's component ids, read in one script (no stale row in between)."""
    return driver.execute_script("return Array.from(document.querySelectorAll("
                                 "'#fleet-table tbody tr'), (r) => r.dataset.component)")


def test_dashboard_in_headless_chromium(tmp_path, live_server, need):
    if CHROMIUM is None or CHROMEDRIVER is None:
        need("chromium/chromedriver not installed: apt-get install chromium chromium-driver")
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import Select, WebDriverWait

    from rulkit.fleet.monitoring.rules import MonitoringRules
    from rulkit.fleet.service.app import create_app
    from rulkit.fleet.service.db import ServiceDB
    from rulkit.fleet.store.sqlite import ComponentStore
    from rulkit.fleet.store.tracker_rows import ROW_FIELDS

    now = time.time()
    rules = MonitoringRules(time_unit="h", lead_time=150.0, stale_after=36 * 3600.0)
    ComponentStore(tmp_path / "fleet.db", rules=rules).close()
    sdb = ServiceDB(tmp_path / "fleet.db")
    _, token = sdb.create_token("write", "browser")
    pump_fleet(sdb, now)
    summary = sdb.summary()
    assert summary["counts"]["alarm"] >= 1 and summary["counts"]["warning"] >= 1
    assert summary["counts"]["stale"] == 1
    user_dir = tempfile.mkdtemp(prefix="rulkit-chromium-")
    shots = [tmp_path / "dashboard-fleet.png", tmp_path / "dashboard-component.png"]
    driver = None
    try:
        with live_server(create_app(sdb)) as srv:
            driver = _driver(user_dir)
            driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument",
                                   {"source": CSP_LISTENER})
            wait = WebDriverWait(driver, 20)
            driver.get(srv.url + "/")
            driver.find_element(By.ID, "token").send_keys(token)
            driver.find_element(By.CSS_SELECTOR, "#token-form button").click()
            wait.until(lambda d: len(rows_of(d, By)) == 12)
            # counts per level, as the API counts them
            for lv in ("alarm", "warning", "ok", "stale"):
                b = driver.find_element(By.CSS_SELECTOR, f'#counts button[data-level="{lv}"]')
                assert b.find_element(By.TAG_NAME, "b").text == str(summary["counts"][lv])
            assert "per-unit log-linear trend" in driver.find_element(By.ID, "estimator").text
            assert "lead time 150 h" in driver.find_element(By.ID, "rules").text
            api = {c["component"]: c for c in sdb.components(limit=50, offset=0)[1]}
            cells = {}
            for tr in rows_of(driver, By):
                name = tr.get_attribute("data-component")
                rul, due = (tr.find_element(By.CSS_SELECTOR, f"td.{k}").text
                            for k in ("rul", "due"))
                cells[name] = rul
                c = api[name]
                if c["rul_state"] == "estimated":  # median [low, high] h and a calendar date
                    q = [js_fmt(c[k]) for k in ("rul", "rul_low", "rul_high")]
                    assert rul == f"{q[0]} [{q[1]}, {q[2]}] h", rul
                    assert due == time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(c["due"]))
                else:
                    assert rul == c["rul_state"]
                assert ("stale" in tr.get_attribute("class")) == c["stale"]
            assert cells["P-108"] == "failed" and cells["P-112"] == "pending"
            assert rows_of(driver, By)[0].get_attribute("data-component") == "P-108"
            shots[0].write_bytes(driver.get_screenshot_as_png())
            # sort by RUL, then by due date: the API's orders
            for sort in ("rul", "due"):
                Select(driver.find_element(By.ID, "sort")).select_by_value(sort)
                want = [c["component"] for c in sdb.components(limit=50, offset=0,
                                                                sort=sort)[1]]
                wait.until(lambda d, w=want: names_of(d) == w)
            assert want[:2] != ["P-108", "P-112"]
            # the stale count filters the table
            driver.find_element(By.CSS_SELECTOR, '#counts button[data-level="stale"]').click()
            wait.until(lambda d: names_of(d) == ["P-111"])
            driver.find_element(By.CSS_SELECTOR, '#counts button[data-level=""]').click()
            wait.until(lambda d: len(names_of(d)) == 12)
            # a component's charts
            warned = max((n for n, c in api.items() if c["level"] == "warning"),
                         key=lambda n: api[n]["rul"])
            row = next(r for r in rows_of(driver, By)
                       if r.get_attribute("data-component") == warned)
            row.find_element(By.CSS_SELECTOR, "button").click()
            wait.until(ec.visibility_of_element_located((By.ID, "detail")))
            hi, rul = (chart_record(driver, wait, c) for c in ("hi-chart", "rul-chart"))
            hist = sdb.history(warned, limit=500)
            check_hi_chart(driver, By, hi, hist, cells[warned])
            check_rul_chart(rul, hist)
            check_alert_tooltip(driver, By, wait, hi, hist)
            assert "RUL " + cells[warned] in driver.find_element(By.ID, "detail-summary").text
            driver.find_element(By.ID, "detail").screenshot(str(shots[1]))
            # open alerts show the table's RUL for their component
            alert_rows = driver.find_elements(By.CSS_SELECTOR, "#alert-table tbody tr")
            assert len(alert_rows) == len(sdb.alerts(state="open", component=None, limit=200,
                                                     offset=0)[1])
            for tr in alert_rows:
                name = tr.get_attribute("data-component")
                assert tr.find_element(By.CSS_SELECTOR, "td.rul").text == cells[name], name
            alarm = next(tr for tr in alert_rows if "level-alarm" in tr.get_attribute("class"))
            assert "measured HI >= 1" in alarm.find_element(By.CSS_SELECTOR, "td.reason").text
            # acknowledge the alarm
            aid = alarm.get_attribute("data-alert-id")
            driver.find_element(By.ID, "ack-by").send_keys("night shift")
            driver.find_element(By.ID, "ack-reason").send_keys("pump swapped")
            driver.find_element(
                By.CSS_SELECTOR, f'#alert-table tr[data-alert-id="{aid}"] button.ack').click()
            wait.until(lambda d: len(d.find_elements(By.CSS_SELECTOR, "#alert-table tbody tr"))
                       == len(alert_rows) - 1)
            assert "acknowledged" in driver.find_element(By.ID, "status").text
            hostile_ids_shown_as_text(driver, wait, sdb, By, ROW_FIELDS)
            logs = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
            assert logs == [], logs
            assert driver.execute_script("return window.__csp") == []
            driver.execute_script("document.body.setAttribute('style', 'color: red')")
            assert driver.execute_script("return window.__csp") == ["style-src-attr"]
    finally:
        if driver is not None:
            driver.quit()
        shutil.rmtree(user_dir, ignore_errors=True)
    for shot in shots:
        assert shot.stat().st_size > 10_000
    if os.environ.get("RULKIT_DOCS_SCREENSHOTS"):
        for shot in shots:
            shutil.copy(shot, Path(os.environ["RULKIT_DOCS_SCREENSHOTS"]) / shot.name)
    total, done = sdb.alerts(state="acknowledged", component=None, limit=10, offset=0)
    assert total == 1 and done[0]["acknowledged"]["by"] == "night shift"
    assert done[0]["acknowledged"]["reason"] == "pump swapped"
    sdb.close()


def chart_record(driver, wait, chart):
    """What uPlot drew into #chart, as the page records it after each draw (data-chart)."""
    wait.until(lambda d: d.find_element("id", chart).get_attribute("data-chart"))
    return json.loads(driver.find_element("id", chart).get_attribute("data-chart"))


def count(values):
    return sum(v is not None for v in values)


def dates_within(labels, first, last):
    """Tick labels that are UTC calendar dates (YYYY-MM-DD) from the day of ``first`` to the
    day of ``last`` (seconds since 1970) and the chart's right margin (under 5 %)."""
    days = [time.strftime("%Y-%m-%d", time.gmtime(t))
            for t in (first, last + 0.05 * (last - first))]
    assert len(labels) >= 3 and all(len(d) == 10 and d[4] == d[7] == "-" for d in labels), \
        labels
    assert days[0] <= min(labels) and max(labels) <= days[1], (labels, days)


def check_hi_chart(driver, by, rec, hist, rul_text):
    """The HI chart: every series with as many points as the history and forecast the API
    returned, the threshold, the RUL on it, dates on the x axis, the time in hours above."""
    legend = [e.text for e in driver.find_elements(by.CSS_SELECTOR,
                                                   "#hi-chart .u-legend .u-series .u-label")
              if e.is_displayed()]
    assert driver.find_elements(by.CSS_SELECTOR, "#hi-chart .uplot canvas")
    h, fc = hist["history"], hist["forecast"]
    want = {"measured HI": count(h["hi"]), "filtered HI": count(h["fhi"]),
            "HI forecast (median)": len(fc["t"]), "forecast band": len(fc["t"]),
            "forecast band (upper)": len(fc["t"]), "RUL interval on the threshold": 2,
            "RUL median": 1}
    assert len(fc["t"]) >= 10 and count(h["fhi"]) >= 10
    assert {k: rec["series"][k] for k in want} == want
    assert rec["threshold"] == hist["threshold"] == 1.0
    assert rec["series"]["failure threshold HI = 1"] >= len(h["t"]) + len(fc["t"])
    assert legend == [k for k in rec["series"] if not k.endswith("(upper)")], legend
    assert rec["rul_label"].startswith("RUL " + rul_text + ", due 20"), rec["rul_label"]
    assert rec["titles"] == ["date (UTC)", "time (h)", "health index"]
    origin = hist["time_origin"]
    dates_within(rec["ticks"]["x"], origin + 3600 * h["t"][0], origin + 3600 * fc["t"][-1])
    ages = [float(v) for v in rec["ticks"]["top"]]
    span = fc["t"][-1] - h["t"][0]
    assert len(ages) >= 3 and h["t"][0] <= min(ages) <= max(ages) <= fc["t"][-1] + 0.05 * span
    assert len(rec["ticks"]["y"]) >= 3
    assert rec["alerts"] == len(hist["alerts"]) >= 1


def js_fmt6(v):
    """The page's fmt(v, 6) for a time in [1e-3, 1e5) (6 significant digits), written again."""
    assert 1e-3 <= abs(v) < 1e5, v
    x = float(f"{v:.6g}")
    return str(int(x)) if x == int(x) else repr(x)


def check_alert_tooltip(driver, by, wait, rec, hist):
    """Hovering an alert's mark on the HI chart shows what the API says the alert was: its
    level, its time (in hours and as a date) and its reason; away from every mark, nothing."""
    from selenium.webdriver.common.action_chains import ActionChains

    over = driver.find_element(by.CSS_SELECTOR, "#hi-chart .u-over")
    tip = driver.find_element(by.CSS_SELECTOR, "#hi-chart .alert-tip")
    width = over.size["width"]
    lefts = {m["id"]: m["left"] for m in rec["marks"]}
    assert sorted(lefts) == sorted(a["id"] for a in hist["alerts"])
    alert = hist["alerts"][-1]
    assert alert["reason"], alert
    left = lefts[alert["id"]]
    ActionChains(driver).move_to_element_with_offset(over, round(left - width / 2), 0).perform()
    wait.until(lambda d: tip.is_displayed())
    assert str(alert["id"]) in tip.get_attribute("data-alert-ids").split()
    date = time.strftime("%Y-%m-%d %H:%M UTC",
                         time.gmtime(hist["time_origin"] + alert["time"] * hist["unit_seconds"]))
    want = f"{alert['level']} at t = {js_fmt6(alert['time'])} ({date}): {alert['reason']}"
    assert want in tip.text.split("\n"), (tip.text, want)
    # 20 px from every mark: no tooltip
    free = next(x for x in range(5, int(width) - 5, 5)
                if all(abs(x - m) > 20 for m in lefts.values()))
    ActionChains(driver).move_to_element_with_offset(over, round(free - width / 2), 0).perform()
    wait.until(lambda d: not tip.is_displayed())


def check_rul_chart(rec, hist):
    """The RUL chart: the median at each acquisition with an estimate, its interval band."""
    h = hist["history"]
    n = count(h["rul"])
    assert n >= 10
    assert rec["series"] == {"RUL median": n, "RUL interval": n, "RUL interval (upper)": n}
    assert rec["titles"] == ["date (UTC)", "time (h)", "RUL (h)"]
    origin = hist["time_origin"]
    dates_within(rec["ticks"]["x"], origin + 3600 * h["t"][0], origin + 3600 * h["t"][-1])
    assert rec["alerts"] == len(hist["alerts"])


def test_vendored_chart_library_matches_its_recorded_hashes():
    """Each vendored file's sha384 is the one its README records and index.html's integrity
    attribute names (the browser refuses a file whose hash differs); the licence is there."""
    (lib,) = VENDOR.iterdir()
    readme = (lib / "README.md").read_text()
    page = (VENDOR.parent / "index.html").read_text()
    assert "MIT License" in (lib / "LICENSE").read_text()
    for name in ("uPlot.iife.min.js", "uPlot.min.css"):
        digest = hashlib.sha384((lib / name).read_bytes()).digest()
        sri = "sha384-" + base64.b64encode(digest).decode()
        assert f"| `{name}` |" in readme and sri in readme, name
        assert f'/static/vendor/{lib.name}/{name}"\n  integrity="{sri}"' in page, name


def hostile_ids_shown_as_text(driver, wait, sdb, by, row_fields):
    """Ids written straight into the tables (whatever ingestion accepts, the page must show
    what the database holds as text): a component row and an open alert each."""
    cols = ", ".join((*row_fields, "max_level"))
    with sdb.store() as s, s._transaction("IMMEDIATE") as conn:
        for name in EVIL:
            conn.execute(f"INSERT INTO components (component, {cols}) SELECT ?, {cols} "
                         "FROM components WHERE component = 'P-101'", (name,))
        conn.execute("INSERT INTO alerts (component, t, level, previous, valid, raised) "
                     "VALUES (?, 1.0, 1, 0, 1, 0.0)", (EVIL[1],))
    driver.find_element(by.CSS_SELECTOR, "#token-form button").click()
    wait.until(lambda d: len(rows_of(d, by)) == 15)
    names = [r.find_element(by.CSS_SELECTOR, "button").text for r in rows_of(driver, by)]
    assert EVIL[0] in names and EVIL[1] in names
    assert "\\x1b[2J\\x1b[31mALARM\\x1b]0;title\\x07\\x0aforged" in names
    assert driver.execute_script("return window.__pwned === undefined")
    assert len(driver.find_elements(by.TAG_NAME, "img")) == 0
    assert len(driver.find_elements(by.TAG_NAME, "script")) == 2  # uPlot and app.js only
    alert_names = [r.find_elements(by.TAG_NAME, "td")[1].text
                   for r in driver.find_elements(by.CSS_SELECTOR, "#alert-table tbody tr")]
    assert EVIL[1] in alert_names


@pytest.fixture(autouse=True)
def _print_screenshot_dir(tmp_path):
    yield
    for shot in sorted(tmp_path.glob("dashboard-*.png")):
        print(f"dashboard screenshot: {shot}")
