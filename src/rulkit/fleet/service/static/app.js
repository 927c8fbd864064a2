// rulkit fleet dashboard: plain DOM, and charts drawn with the vendored uPlot (no external
// assets). Every string from the API is inserted with textContent (never innerHTML), and
// control characters (terminal escape sequences, newlines) are shown as visible \xNN escapes.
// The RUL shown everywhere (fleet table, alerts, charts) is the one the API returns: the
// median of the estimator in force and its interval, in the data's time unit.
"use strict";

const state = { token: sessionStorage.getItem("rulkit-token") || "", offset: 0, limit: 50,
  total: 0, selected: null, summary: null };

function $(id) { return document.getElementById(id); }

function visible(s) {
  return String(s).replace(/[\u0000-\u001f\u007f-\u009f]/g,
    (c) => "\\x" + c.charCodeAt(0).toString(16).padStart(2, "0"));
}

function fmt(v, digits = 3) {
  if (v === null || v === undefined || !Number.isFinite(v)) return "–";
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) return v.toExponential(digits - 1);
  return String(Number(v.toPrecision(digits)));
}

function unit() { return state.summary ? state.summary.time_unit : ""; }

// the RUL of a component item (or an alert's current state): median [low, high] unit
function rulText(c) {
  if (!c) return "–";
  if (c.rul_state === "failed") return "failed";
  if (c.rul_state === "pending") return "pending";
  const q = (v) => (v === null ? "∞" : fmt(v));
  return q(c.rul) + " [" + q(c.rul_low) + ", " + q(c.rul_high) + "]" +
    (unit() ? " " + unit() : "");
}

function dateText(seconds) {
  if (seconds === null || seconds === undefined) return "–";
  return new Date(seconds * 1000).toISOString().slice(0, 16).replace("T", " ") + " UTC";
}

function ageText(seconds) {
  if (seconds === null || seconds === undefined || !state.summary) return "";
  const d = state.summary.now - seconds;
  if (d < 0) return "";
  const [n, u] = d >= 86400 ? [d / 86400, "d"] : d >= 3600 ? [d / 3600, "h"] : [d / 60, "min"];
  return fmt(n, 2) + " " + u + " ago";
}

function setStatus(msg, error = false) {
  const el = $("status");
  el.textContent = msg;
  el.className = error ? "error" : "";
}

async function api(path, opts = {}) {
  const headers = Object.assign({ Authorization: "Bearer " + state.token }, opts.headers || {});
  const res = await fetch(path, Object.assign({}, opts, { headers }));
  let body = null;
  try { body = await res.json(); } catch (e) { body = null; }
  if (!res.ok) {
    const detail = body && typeof body.detail === "string" ? body.detail : res.statusText;
    throw new Error(res.status + ": " + detail);
  }
  return body;
}

function cell(tr, text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  tr.appendChild(td);
  return td;
}

async function loadSummary() {
  const s = await api("/api/v1/summary");
  state.summary = s;
  for (const b of $("counts").querySelectorAll("button.count")) {
    const lv = b.dataset.level;
    b.querySelector("b").textContent = String(lv ? s.counts[lv] : s.total);
    b.classList.toggle("active", $("level-filter").value === lv);
  }
  $("estimator").textContent = "RUL: " + s.estimator_label +
    (s.time_unit ? ", in " + s.time_unit : ", in the time unit of the data") +
    (s.calendar ? "; due dates on the calendar (UTC)" : "; no due dates (not a duration)");
  const stale = s.rules.stale_after === null ? "staleness not judged"
    : "stale after " + fmt(s.rules.stale_after / 3600, 3) + " h without an acquisition";
  $("rules").textContent = "alarm: " + s.rules.alarm + "; warning: " + s.rules.warning +
    "; " + stale;
  const ul = $("model-warnings");
  ul.replaceChildren();
  for (const w of s.model_warnings) {
    const li = document.createElement("li");
    li.textContent = "model warning: " + visible(w);
    ul.appendChild(li);
  }
  $("rul-head").textContent = "RUL median [" + fmt(100 * (1 - s.interval) / 2) + " %, " +
    fmt(100 * (1 + s.interval) / 2) + " %]" + (s.time_unit ? " (" + s.time_unit + ")" : "");
}

async function loadFleet() {
  const level = $("level-filter").value;
  const q = new URLSearchParams({ limit: state.limit, offset: state.offset,
    sort: $("sort").value });
  if (level) q.set("level", level);
  const page = await api("/api/v1/components?" + q.toString());
  state.total = page.total;
  const tbody = $("fleet-table").querySelector("tbody");
  tbody.replaceChildren();
  for (const c of page.items) {
    const tr = document.createElement("tr");
    tr.className = "level-" + c.level + (c.stale ? " stale" : "");
    tr.dataset.level = c.level;
    tr.dataset.component = c.component;
    const td = cell(tr, "", "name");
    const btn = document.createElement("button");
    btn.type = "button";
    btn.className = "open-component";
    btn.textContent = visible(c.component);
    btn.addEventListener("click", () => loadDetail(c.component));
    td.appendChild(btn);
    cell(tr, c.level + (c.stale ? " · stale" : ""), "level");
    cell(tr, rulText(c), "rul");
    cell(tr, dateText(c.due), "due");
    cell(tr, fmt(c.hi), "hi");
    cell(tr, "t = " + fmt(c.last_time, 6) + (unit() ? " " + unit() : ""), "last-time");
    const seen = cell(tr, dateText(c.last_seen), "seen");
    const age = ageText(c.last_seen);
    if (age) seen.title = age;
    cell(tr, String(c.n), "n");
    tbody.appendChild(tr);
  }
  const last = Math.min(state.offset + page.items.length, page.total);
  $("fleet-count").textContent = "(" + (page.total ? state.offset + 1 : 0) + "–" + last +
    " of " + page.total + ")";
  $("prev-page").disabled = state.offset === 0;
  $("next-page").disabled = last >= page.total;
}

async function loadAlerts() {
  const page = await api("/api/v1/alerts?state=open&limit=200");
  const tbody = $("alert-table").querySelector("tbody");
  tbody.replaceChildren();
  for (const a of page.items) {
    const tr = document.createElement("tr");
    tr.className = "level-" + a.level;
    tr.dataset.alertId = String(a.id);
    tr.dataset.component = a.component;
    cell(tr, String(a.id));
    cell(tr, visible(a.component), "name");
    cell(tr, a.level);
    cell(tr, dateText(a.raised) + " (t = " + fmt(a.time, 6) + ")", "raised");
    cell(tr, a.reason === null ? "" : visible(a.reason), "reason");
    cell(tr, rulText(a.current), "rul");
    cell(tr, a.current ? dateText(a.current.due) : "–", "due");
    const td = cell(tr, "");
    const btn = document.createElement("button");
    btn.type = "button";
    btn.className = "ack";
    btn.textContent = "Acknowledge";
    btn.addEventListener("click", () => ack(a.id));
    td.appendChild(btn);
    tbody.appendChild(tr);
  }
  $("alert-count").textContent = "(" + page.total + ")";
}

async function ack(id) {
  const by = $("ack-by").value.trim();
  const reason = $("ack-reason").value.trim();
  if (!by || !reason) { setStatus("enter who acknowledges and why", true); return; }
  try {
    await api("/api/v1/alerts/" + id + "/ack", {
      method: "POST", headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ by, reason }),
    });
    setStatus("alert " + id + " acknowledged");
    await loadAlerts();
    if (state.selected !== null) await loadDetail(state.selected);
  } catch (e) { setStatus(e.message, true); }
}

// ------------------------------------------------------------------------------- charts
// Drawn with uPlot (static/vendor/uplot-*/, MIT licence): canvas, so after each draw the
// chart's container carries data-chart, a JSON record of what was drawn (points per series,
// the threshold, axis titles, the tick labels as drawn, alert marks, the RUL text) for tests
// and assistive tools.
const COLOR = { measured: "#444", filtered: "#2a7", forecast: "#0645ad",
  band: "rgba(6, 69, 173, 0.22)", threshold: "#c00", warning: "#e80", rul: "#153",
  rulBand: "rgba(34, 170, 119, 0.28)" };
const charts = {};

function niceTicks(lo, hi, n) {
  const span = hi - lo;
  if (!(span > 0)) return [lo];
  const raw = span / n;
  const mag = Math.pow(10, Math.floor(Math.log10(raw)));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => span / s <= n) || 10 * mag;
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * span; v += step) {
    out.push(Number(v.toPrecision(12)));
  }
  return out;
}

// The x axis of a component's charts: calendar seconds shown as UTC dates (and the data's
// time on a top axis) when the time unit is a duration with an origin, else the data's time.
function timeAxis(h) {
  const u = h.time_unit, title = "time" + (u ? " (" + u + ")" : "");
  if (h.time_origin === null || h.unit_seconds === null) {
    return { x: (t) => t, time: false, title };
  }
  return { x: (t) => h.time_origin + t * h.unit_seconds, time: true, title: "date (UTC)",
    ageTitle: title, age: (s) => (s - h.time_origin) / h.unit_seconds };
}

// the x scale: the data's span and 3 % more on the right (a mark at the end stays visible)
function xScale(ta) {
  return { time: ta.time, range: (u, lo, hi) => (hi > lo ? [lo, hi + 0.03 * (hi - lo)]
    : [lo - 1, hi + 1]) };
}

function dateLabel(seconds, span) {
  const d = new Date(seconds * 1000).toISOString();
  return span > 5 * 86400 ? d.slice(0, 10) : d.slice(5, 10) + " " + d.slice(11, 16);
}

// uPlot's aligned columns: the sorted union of the series' x, each series null off its points
function align(columns) {
  const xs = Array.from(new Set(columns.flatMap(([x]) => x))).sort((a, b) => a - b);
  const at = new Map(xs.map((x, i) => [x, i]));
  const out = [xs];
  for (const [x, y] of columns) {
    const col = new Array(xs.length).fill(null);
    x.forEach((v, i) => { if (y[i] !== null && y[i] !== undefined) col[at.get(v)] = y[i]; });
    out.push(col);
  }
  return out;
}

function line(label, stroke, more = {}) {
  return Object.assign({ label, stroke, width: 1.5, spanGaps: true, points: { show: false } },
    more);
}

// the axes (bottom: dates or time, top: time when dated, left: yTitle), recording the tick
// labels each one draws into drawn[key]
function axes(ta, yTitle, drawn) {
  const rec = (key, f) => (u, splits) => (drawn[key] = splits.map((s) => f(s, u)));
  const out = [{ scale: "x", label: ta.title, labelSize: 18, size: 36, space: 90,
    values: rec("x", (s, u) => (ta.time ? dateLabel(s, u.scales.x.max - u.scales.x.min)
      : fmt(s, 6))) }];
  if (ta.time) {
    out.push({ scale: "x", side: 0, label: ta.ageTitle, labelSize: 18, size: 30, space: 60,
      grid: { show: false },
      splits: (u, i, lo, hi) => niceTicks(ta.age(lo), ta.age(hi), 7).map(
        (a) => lo + (a - ta.age(lo)) * (hi - lo) / (ta.age(hi) - ta.age(lo))),
      values: rec("top", (s) => fmt(ta.age(s), 6)) });
  }
  out.push({ scale: "y", label: yTitle, labelSize: 18, size: 56,
    values: rec("y", (s) => fmt(s, 4)) });
  return out;
}

function alertMarks(u, alerts, x) {
  const ctx = u.ctx, dpr = window.devicePixelRatio || 1;
  ctx.save();
  ctx.lineWidth = 2 * dpr;
  ctx.setLineDash([4 * dpr, 3 * dpr]);
  for (const a of alerts) {
    const px = u.valToPos(x(a.time), "x", true);
    ctx.strokeStyle = a.level === "alarm" ? COLOR.threshold : COLOR.warning;
    ctx.beginPath();
    ctx.moveTo(px, u.bbox.top);
    ctx.lineTo(px, u.bbox.top + u.bbox.height);
    ctx.stroke();
  }
  ctx.restore();
}

// what an alert was: its level, when (the data's time, and the date when dated), why
function alertText(a, ta) {
  return a.level + " at t = " + fmt(a.time, 6) + (ta.time ? " (" + dateText(ta.x(a.time)) + ")"
    : "") + (a.reason === null ? "" : ": " + visible(a.reason))
    + (a.acknowledged ? " (acknowledged by " + visible(a.acknowledged.by) + ")" : "");
}

// a uPlot plugin: while the pointer is within 4 px of an alert's mark, a tooltip over the
// plot says what the alert was (text only, no markup)
function alertTips(alerts, ta) {
  let tip = null;
  const show = (u) => {
    const left = u.cursor.left;
    const near = left === null || left < 0 ? [] : alerts.filter(
      (a) => Math.abs(u.valToPos(ta.x(a.time), "x") - left) <= 4);
    tip.hidden = near.length === 0;
    if (tip.hidden) return;
    tip.textContent = near.map((a) => alertText(a, ta)).join("\n");
    tip.dataset.alertIds = near.map((a) => a.id).join(" ");
    tip.style.left = Math.min(left + 8, u.over.clientWidth * 0.6) + "px";
    tip.style.top = Math.max(u.cursor.top || 0, 0) + "px";
  };
  return { hooks: {
    init: [(u) => {
      tip = document.createElement("div");
      tip.className = "alert-tip";
      tip.hidden = true;
      u.over.appendChild(tip);
    }],
    setCursor: [show],
  } };
}

// where each alert's mark is drawn: CSS pixels from the plot's left edge (u.over)
function markPositions(u, alerts, ta) {
  return alerts.map((a) => ({ id: a.id, left: u.valToPos(ta.x(a.time), "x") }));
}

// text on the canvas, right-aligned at x but never left of minX; returns its right end
function canvasText(u, text, x, minX, y, color) {
  const ctx = u.ctx, dpr = window.devicePixelRatio || 1;
  ctx.save();
  ctx.font = 12 * dpr + "px system-ui, sans-serif";
  ctx.fillStyle = color;
  const right = Math.max(x, minX + ctx.measureText(text).width);
  ctx.textAlign = "right";
  ctx.fillText(text, right, y);
  ctx.restore();
  return right;
}

// draw (or redraw) a uPlot chart into the element id; record() gives the data-chart extras
function plot(id, opts, data, record) {
  const el = $(id);
  if (charts[id]) charts[id].destroy();
  el.replaceChildren();
  delete el.dataset.chart;
  if (!data) { el.textContent = opts; charts[id] = null; return; }
  const drawn = {};
  opts.axes = opts.axes(drawn);
  const draw = opts.hooks.draw;
  opts.hooks.draw = [(u) => {
    draw.forEach((f) => f(u));
    const series = {};
    u.series.slice(1).forEach((s, i) => {
      series[s.label] = data[i + 1].filter((v) => v !== null).length;
    });
    el.dataset.chart = JSON.stringify(Object.assign({ series, ticks: drawn,
      titles: u.axes.map((a) => a.label) }, record(u)));
  }];
  Object.assign(opts, { width: 900, legend: { live: false },
    tzDate: (ts) => uPlot.tzDate(new Date(ts * 1e3), "Etc/UTC") });
  const u = charts[id] = new uPlot(opts, data, el);
  // a band's upper edge is drawn as the band, named once in the legend (its lower edge)
  const hide = new Set(opts.series.filter((s) => s.inLegend === false).map((s) => s.label));
  for (const row of u.root.querySelectorAll(".u-legend .u-series")) {
    if (hide.has(row.querySelector(".u-label").textContent)) row.classList.add("unlisted");
  }
}

// where the RUL interval meets the threshold: [low, median, high] end times (null if none)
function rulOnThreshold(h, xEnd) {
  const now = h.now;
  if (now.rul_state !== "estimated") return null;
  const t0 = now.last_time;
  return [t0 + now.rul_low, now.rul === null ? null : t0 + now.rul,
    now.rul_high === null ? xEnd : Math.min(t0 + now.rul_high, Math.max(xEnd, t0 + now.rul))];
}

// the HI chart's columns: measured, filtered, forecast median, low, high, the threshold,
// the RUL interval and median on it, and the alarm rule's HI when it is not the threshold
function hiColumns(h, fc, on, x) {
  const H = h.history, thr = h.threshold, X = (ts) => ts.map(x);
  const ends = on ? [on[0], on[2]] : [];
  const median = on && on[1] !== null ? [on[1]] : [];
  const allT = H.t.concat(fc.t, ends, median);
  const cols = [[X(H.t), H.hi], [X(H.t), H.fhi], [X(fc.t), fc.hi], [X(fc.t), fc.hi_low],
    [X(fc.t), fc.hi_high], [X(allT), allT.map(() => thr)], [X(ends), ends.map(() => thr)],
    [X(median), median.map(() => thr)]];
  if (h.alarm_hi !== thr) cols.push([X(allT), allT.map(() => h.alarm_hi)]);
  return align(cols);
}

function hiChart(h) {
  const H = h.history, fc = h.forecast || { t: [], hi: [], hi_low: [], hi_high: [] };
  if (H.t.length === 0) { plot("hi-chart", "no acquisition yet", null); return; }
  const ta = timeAxis(h), thr = h.threshold;
  const on = rulOnThreshold(h, Math.max(...H.t, ...fc.t));
  const data = hiColumns(h, fc, on, ta.x);
  const alarmLine = h.alarm_hi === thr ? [] : [line("alarm rule HI = " + fmt(h.alarm_hi),
    COLOR.warning, { dash: [2, 3] })];
  const top = Math.max(...H.hi.filter((v) => v !== null), ...fc.hi_high.filter(
    (v) => v !== null), thr);
  const label = on ? "RUL " + rulText(h.now) + (h.now.due === null ? ""
    : ", due " + dateText(h.now.due)) : "";
  const thrLabel = "failure threshold HI = " + fmt(thr);
  plot("hi-chart", {
    height: 320, axes: (drawn) => axes(ta, "health index", drawn),
    scales: { x: xScale(ta), y: { range: [0, Math.max(Math.min(top * 1.05, 2 * thr),
      1.15 * thr)] } },
    series: [{ label: ta.title },
      { label: "measured HI", stroke: COLOR.measured, paths: () => null,
        points: { show: true, size: 4, fill: COLOR.measured } },
      line("filtered HI", COLOR.filtered),
      line("HI forecast (median)", COLOR.forecast, { width: 2, dash: [6, 4] }),
      line("forecast band", COLOR.band, { width: 0 }),
      line("forecast band (upper)", COLOR.band, { width: 0, inLegend: false }),
      line(thrLabel, COLOR.threshold, { dash: [8, 4] }),
      line("RUL interval on the threshold", COLOR.warning, { width: 6 }),
      { label: "RUL median", stroke: COLOR.threshold, paths: () => null,
        points: { show: true, size: 9, fill: COLOR.threshold } }, ...alarmLine],
    bands: [{ series: [5, 4], fill: COLOR.band }],
    hooks: { draw: [(u) => {
      alertMarks(u, h.alerts, ta.x);
      const dpr = window.devicePixelRatio || 1, y = u.valToPos(thr, "y", true) - 6 * dpr;
      const end = canvasText(u, thrLabel, 0, u.bbox.left + 6 * dpr, y, COLOR.threshold);
      // left of the interval, where the band is still under the threshold
      if (label) canvasText(u, label, u.valToPos(ta.x(on[0]), "x", true) - 10 * dpr,
        end + 16 * dpr, y, "#222");
    }] },
    plugins: [alertTips(h.alerts, ta)],
  }, data, (u) => ({ threshold: thr, threshold_label: thrLabel, rul_label: label,
    alerts: h.alerts.length, marks: markPositions(u, h.alerts, ta) }));
}

function rulChart(h) {
  const H = h.history, u = h.time_unit;
  const known = H.rul.map((v) => v !== null);
  if (H.t.length === 0 || !known.some(Boolean)) {
    plot("rul-chart", "no RUL estimated yet", null);
    return;
  }
  const ta = timeAxis(h), X = (ts) => ts.map(ta.x);
  const medians = H.rul.filter((v) => v !== null);
  const cut = 2 * Math.max(...medians) || 1;  // an unbounded interval: cut at 2x
  const high = H.rul_high.map((v, i) => (known[i] ? Math.min(v === null ? cut : v, cut)
    : null));
  const low = H.rul_low.map((v, i) => (known[i] ? v : null));
  const data = align([[X(H.t), H.rul], [X(H.t), low], [X(H.t), high]]);
  const yTitle = "RUL" + (u ? " (" + u + ")" : "");
  plot("rul-chart", {
    height: 260, axes: (drawn) => axes(ta, yTitle, drawn),
    scales: { x: xScale(ta), y: { range: [0, Math.max(...high.filter(
      (v) => v !== null), ...medians) * 1.05 || 1] } },
    series: [{ label: ta.title }, line("RUL median", COLOR.rul, { width: 2 }),
      line("RUL interval", COLOR.rulBand, { width: 0 }),
      line("RUL interval (upper)", COLOR.rulBand, { width: 0, inLegend: false })],
    bands: [{ series: [3, 2], fill: COLOR.rulBand }],
    hooks: { draw: [(p) => alertMarks(p, h.alerts, ta.x)] },
    plugins: [alertTips(h.alerts, ta)],
  }, data, (p) => ({ alerts: h.alerts.length, rul_now: rulText(h.now),
    marks: markPositions(p, h.alerts, ta) }));
}

async function loadDetail(name) {
  state.selected = name;
  // the id in the query: a browser rewrites the path segments "." and ".."
  const h = await api("/api/v1/history?component=" + encodeURIComponent(name));
  $("detail").hidden = false;
  $("detail-name").textContent = visible(name);
  const c = h.now;
  $("detail-summary").textContent = c.level + (c.stale ? " (stale)" : "") + "; RUL " +
    rulText(c) + "; due " + dateText(c.due) + "; " + h.n + " acquisitions (" + h.returned +
    " shown), last seen " + dateText(c.last_seen) + "; " + h.alerts.length + " alerts";
  hiChart(h);
  rulChart(h);
}

async function refresh() {
  if (!state.token) { setStatus("enter an API token (rulkit token create)"); return; }
  try {
    await loadSummary();
    await Promise.all([loadFleet(), loadAlerts()]);
    setStatus("updated " + new Date().toISOString().slice(11, 19) + " UTC");
  } catch (e) { setStatus(e.message, true); }
}

document.addEventListener("DOMContentLoaded", () => {
  $("token").value = state.token;
  $("token-form").addEventListener("submit", (ev) => {
    ev.preventDefault();
    state.token = $("token").value.trim();
    sessionStorage.setItem("rulkit-token", state.token);
    refresh();
  });
  $("level-filter").addEventListener("change", () => { state.offset = 0; refresh(); });
  $("sort").addEventListener("change", () => { state.offset = 0; refresh(); });
  for (const b of $("counts").querySelectorAll("button.count")) {
    b.addEventListener("click", () => {
      $("level-filter").value = b.dataset.level;
      state.offset = 0;
      refresh();
    });
  }
  $("prev-page").addEventListener("click", () => {
    state.offset = Math.max(0, state.offset - state.limit); refresh();
  });
  $("next-page").addEventListener("click", () => { state.offset += state.limit; refresh(); });
  refresh();
});
