// rulkit fleet dashboard: plain DOM + SVG drawn here, no external assets (the charts are SVG
// elements with classes, so a test can check that each one is drawn). Every string from the
// API is inserted with textContent (never innerHTML), and control characters (terminal escape
// sequences, newlines) are shown as visible \xNN escapes. The RUL shown everywhere (fleet
// table, alerts, charts) is the one the API returns: the median of the estimator in force
// and its interval, in the data's time unit.
"use strict";

const state = { token: sessionStorage.getItem("rulkit-token") || "", offset: 0, limit: 50,
  total: 0, selected: null, summary: null };
const NS = "http://www.w3.org/2000/svg";

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
function svgEl(name, attrs, parent) {
  const el = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  if (parent) parent.appendChild(el);
  return el;
}

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

// axes with ticks and titles; cfg: {x0, x1, y0, y1, xLabel, yLabel, origin, unitSeconds}
function frame(svg, cfg) {
  svg.replaceChildren();
  const W = Number(svg.getAttribute("width")), H = Number(svg.getAttribute("height"));
  const dated = cfg.origin !== null && cfg.origin !== undefined && cfg.unitSeconds;
  const m = { l: 62, r: 16, t: 12, b: dated ? 58 : 42 };
  const sx = (x) => m.l + (x - cfg.x0) / (cfg.x1 - cfg.x0) * (W - m.l - m.r);
  const sy = (y) => H - m.b - (y - cfg.y0) / (cfg.y1 - cfg.y0) * (H - m.t - m.b);
  const g = svgEl("g", {}, svg);
  for (const v of niceTicks(cfg.y0, cfg.y1, 5)) {
    svgEl("line", { x1: m.l, x2: W - m.r, y1: sy(v), y2: sy(v), class: "grid" }, g);
    svgEl("text", { x: m.l - 6, y: sy(v) + 4, "text-anchor": "end", class: "tick y-tick" }, g)
      .textContent = fmt(v, 4);
  }
  for (const v of niceTicks(cfg.x0, cfg.x1, 7)) {
    svgEl("line", { x1: sx(v), x2: sx(v), y1: H - m.b, y2: H - m.b + 4, class: "axis" }, g);
    svgEl("text", { x: sx(v), y: H - m.b + 16, "text-anchor": "middle", class: "tick x-tick" },
      g).textContent = fmt(v, 6);
    if (dated) {
      const d = new Date((cfg.origin + v * cfg.unitSeconds) * 1000).toISOString();
      svgEl("text", { x: sx(v), y: H - m.b + 30, "text-anchor": "middle",
        class: "tick date-tick" }, g).textContent = d.slice(5, 10) + " " + d.slice(11, 16);
    }
  }
  svgEl("line", { x1: m.l, y1: H - m.b, x2: W - m.r, y2: H - m.b, class: "axis" }, g);
  svgEl("line", { x1: m.l, y1: m.t, x2: m.l, y2: H - m.b, class: "axis" }, g);
  svgEl("text", { x: (m.l + W - m.r) / 2, y: H - 6, "text-anchor": "middle",
    class: "axis-title x-title" }, g).textContent = cfg.xLabel +
    (dated ? " / date (UTC, MM-DD hh:mm)" : "");
  svgEl("text", { x: 14, y: (m.t + H - m.b) / 2, "text-anchor": "middle", class:
    "axis-title y-title", transform: "rotate(-90 14 " + (m.t + H - m.b) / 2 + ")" }, g)
    .textContent = cfg.yLabel;
  const clampY = (v) => sy(Math.min(Math.max(v, cfg.y0), cfg.y1));
  return { g, sx, sy, clampY, m, W, H };
}

function polyline(f, xs, ys, cls) {
  const pts = [];
  xs.forEach((x, i) => { if (ys[i] !== null) pts.push(f.sx(x) + "," + f.clampY(ys[i])); });
  if (pts.length) svgEl("polyline", { points: pts.join(" "), class: cls }, f.g);
}

function band(f, xs, lo, hi, cls) {
  const up = [], down = [];
  xs.forEach((x, i) => {
    if (lo[i] !== null && hi[i] !== null) {
      up.push(f.sx(x) + "," + f.clampY(hi[i]));
      down.unshift(f.sx(x) + "," + f.clampY(lo[i]));
    }
  });
  if (up.length) svgEl("polygon", { points: up.concat(down).join(" "), class: cls }, f.g);
}

function alertMarks(f, alerts) {
  for (const a of alerts) {
    const line = svgEl("line", { x1: f.sx(a.time), x2: f.sx(a.time), y1: f.m.t,
      y2: f.H - f.m.b, class: "alert-mark alert-" + a.level }, f.g);
    svgEl("title", {}, line).textContent = a.level + " at t = " + fmt(a.time, 6) +
      (a.acknowledged ? " (acknowledged)" : "");
  }
}

function finite(values) { return values.filter((v) => v !== null && Number.isFinite(v)); }

function hiChart(h) {
  const svg = $("hi-chart");
  const H = h.history, fc = h.forecast, u = h.time_unit;
  const xs = H.t.concat(fc ? fc.t : []);
  const ys = finite(H.hi).concat(fc ? finite(fc.hi_high) : []).concat([h.threshold]);
  if (H.t.length === 0) { svg.replaceChildren(); return; }
  let x0 = Math.min(...xs), x1 = Math.max(...xs);
  if (x1 === x0) { x0 -= 1; x1 += 1; }
  const f = frame(svg, { x0, x1, y0: 0, y1: Math.min(Math.max(...ys) * 1.05, 2 * h.threshold),
    xLabel: "time" + (u ? " (" + u + ")" : ""), yLabel: "health index",
    origin: h.time_origin, unitSeconds: h.unit_seconds });
  if (fc) {
    band(f, fc.t, fc.hi_low, fc.hi_high, "forecast-band");
    polyline(f, fc.t, fc.hi, "forecast");
  }
  const ty = f.sy(h.threshold);
  svgEl("line", { x1: f.m.l, x2: f.W - f.m.r, y1: ty, y2: ty, class: "threshold" }, f.g);
  svgEl("text", { x: f.m.l + 4, y: ty - 4, class: "threshold-label" }, f.g).textContent =
    "failure threshold HI = " + fmt(h.threshold);
  if (h.alarm_hi !== h.threshold) {
    const ay = f.sy(h.alarm_hi);
    svgEl("line", { x1: f.m.l, x2: f.W - f.m.r, y1: ay, y2: ay, class: "alarm-line" }, f.g);
  }
  const now = h.now;
  if (now.rul_state === "estimated") {  // the RUL interval where the band meets the threshold
    const t0 = now.last_time;
    const hiEnd = now.rul_high === null ? x1 : Math.min(t0 + now.rul_high, x1);
    svgEl("line", { x1: f.sx(t0 + now.rul_low), x2: f.sx(hiEnd), y1: ty, y2: ty,
      class: "rul-interval" }, f.g);
    if (now.rul !== null) {
      const x = f.sx(t0 + now.rul);
      svgEl("circle", { cx: x, cy: ty, r: 4, class: "rul-median" }, f.g);
      svgEl("text", { x: Math.min(x, f.W - f.m.r - 4), y: ty - 8, "text-anchor": "end",
        class: "rul-label" }, f.g).textContent = "RUL " + rulText(now) +
        (now.due === null ? "" : ", due " + dateText(now.due));
    }
  }
  H.t.forEach((x, i) => {
    if (H.hi[i] !== null) svgEl("circle", { cx: f.sx(x), cy: f.clampY(H.hi[i]), r: 2,
      class: "dot" }, f.g);
  });
  alertMarks(f, h.alerts);
}

function rulChart(h) {
  const svg = $("rul-chart");
  const H = h.history, u = h.time_unit;
  const known = H.rul.map((v) => v !== null);
  const ys = finite(H.rul).concat(finite(H.rul_low)).concat(
    finite(H.rul_high.filter((v, i) => known[i])));
  if (H.t.length === 0 || ys.length === 0) {
    svg.replaceChildren();
    svgEl("text", { x: 410, y: 120, "text-anchor": "middle" }, svg).textContent =
      "no RUL estimated yet";
    return;
  }
  let x0 = Math.min(...H.t), x1 = Math.max(...H.t);
  if (x1 === x0) { x0 -= 1; x1 += 1; }
  const top = Math.max(...finite(H.rul)) * 2 || 1;  // an unbounded interval: cut at 2x
  const y1 = Math.min(Math.max(...ys), top) || 1;
  const f = frame(svg, { x0, x1, y0: 0, y1,
    xLabel: "time" + (u ? " (" + u + ")" : ""), yLabel: "RUL" + (u ? " (" + u + ")" : ""),
    origin: h.time_origin, unitSeconds: h.unit_seconds });
  const hiBand = H.rul_high.map((v, i) => (known[i] ? (v === null ? y1 : v) : null));
  band(f, H.t, H.rul_low.map((v, i) => (known[i] ? v : null)), hiBand, "band");
  polyline(f, H.t, H.rul, "rul-line");
  alertMarks(f, h.alerts);
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
