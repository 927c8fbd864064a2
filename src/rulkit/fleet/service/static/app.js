// rulkit fleet dashboard: plain DOM + SVG, no external assets. Every string from the API is
// inserted with textContent (never innerHTML), and control characters (terminal escape
// sequences, newlines) are shown as visible \xNN escapes.
"use strict";

const state = { token: sessionStorage.getItem("rulkit-token") || "", offset: 0, limit: 50,
  total: 0, selected: null };
const NS = "http://www.w3.org/2000/svg";

function $(id) { return document.getElementById(id); }

function visible(s) {
  return String(s).replace(/[\u0000-\u001f\u007f-\u009f]/g,
    (c) => "\\x" + c.charCodeAt(0).toString(16).padStart(2, "0"));
}

function fmt(v, digits = 4) {
  if (v === null || v === undefined) return "–";
  const a = Math.abs(v);
  if (a !== 0 && (a >= 1e5 || a < 1e-3)) return v.toExponential(digits - 1);
  return String(Number(v.toPrecision(digits)));
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

function rulText(r) {
  return fmt(r.rul) + " [" + fmt(r.rul_low) + ", " + fmt(r.rul_high) + "]";
}

async function loadFleet() {
  const level = $("level-filter").value;
  const q = new URLSearchParams({ limit: state.limit, offset: state.offset });
  if (level) q.set("level", level);
  const page = await api("/api/v1/components?" + q.toString());
  state.total = page.total;
  const tbody = $("fleet-table").querySelector("tbody");
  tbody.replaceChildren();
  for (const c of page.items) {
    const tr = document.createElement("tr");
    tr.className = "level-" + c.level;
    tr.dataset.level = c.level;
    const td = cell(tr, "", "name");
    const btn = document.createElement("button");
    btn.type = "button";
    btn.className = "open-component";
    btn.textContent = visible(c.component);
    btn.addEventListener("click", () => loadDetail(c.component));
    td.appendChild(btn);
    cell(tr, c.level);
    cell(tr, fmt(c.hi));
    cell(tr, fmt(c.fhi));
    cell(tr, rulText(c));
    cell(tr, c.valid ? "yes" : "no");
    cell(tr, fmt(c.last_time, 6));
    cell(tr, String(c.n));
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
    cell(tr, String(a.id));
    cell(tr, visible(a.component), "name");
    cell(tr, a.level);
    cell(tr, fmt(a.time, 6));
    cell(tr, fmt(a.fhi));
    cell(tr, rulText(a));
    cell(tr, new Date(a.raised * 1000).toISOString().replace(".000Z", "Z"));
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

function svgEl(name, attrs, parent) {
  const el = document.createElementNS(NS, name);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  if (parent) parent.appendChild(el);
  return el;
}

// series: [{type: "dots"|"line"|"band", y | lo, hi, color}], marks: [{x, color}];
// focus: optional booleans, the points that set the y range (others are clipped)
function chart(svg, xs, series, marks, focus) {
  svg.replaceChildren();
  const W = Number(svg.getAttribute("width")), H = Number(svg.getAttribute("height"));
  const m = { l: 60, r: 10, t: 10, b: 28 };
  const useFocus = focus && focus.filter(Boolean).length >= 2;
  const ys = [];
  for (const s of series) for (const k of ["y", "lo", "hi"]) {
    if (s[k]) s[k].forEach((v, i) => {
      if (v !== null && Number.isFinite(v) && (!useFocus || focus[i])) ys.push(v);
    });
  }
  if (xs.length === 0 || ys.length === 0) {
    svgEl("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, svg).textContent = "no data";
    return;
  }
  let x0 = Math.min(...xs), x1 = Math.max(...xs);
  let y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (x1 === x0) { x0 -= 1; x1 += 1; }
  if (y1 === y0) { y0 -= 1; y1 += 1; }
  const sx = (x) => m.l + (x - x0) / (x1 - x0) * (W - m.l - m.r);
  const sy = (y) => H - m.b - (y - y0) / (y1 - y0) * (H - m.t - m.b);
  svgEl("line", { x1: m.l, y1: H - m.b, x2: W - m.r, y2: H - m.b, stroke: "#888" }, svg);
  svgEl("line", { x1: m.l, y1: m.t, x2: m.l, y2: H - m.b, stroke: "#888" }, svg);
  const label = (x, y, text, anchor) => {
    svgEl("text", { x, y, "text-anchor": anchor, "font-size": 11, fill: "#444" }, svg)
      .textContent = text;
  };
  label(m.l - 4, m.t + 10, fmt(y1), "end");
  label(m.l - 4, H - m.b, fmt(y0), "end");
  label(m.l, H - 8, fmt(x0, 6), "start");
  label(W - m.r, H - 8, fmt(x1, 6), "end");
  const clampY = (v) => sy(Math.min(Math.max(v, y0), y1));
  for (const s of series) {
    if (s.type === "band") {
      const up = [], down = [];
      xs.forEach((x, i) => {
        if (s.lo[i] !== null && s.hi[i] !== null) {
          up.push(sx(x) + "," + clampY(s.hi[i]));
          down.unshift(sx(x) + "," + clampY(s.lo[i]));
        }
      });
      if (up.length) svgEl("polygon", { points: up.concat(down).join(" "), fill: s.color,
        "fill-opacity": 0.25, stroke: "none", class: "band" }, svg);
    } else if (s.type === "line") {
      const pts = [];
      xs.forEach((x, i) => { if (s.y[i] !== null) pts.push(sx(x) + "," + clampY(s.y[i])); });
      svgEl("polyline", { points: pts.join(" "), fill: "none", stroke: s.color,
        "stroke-width": 1.5, class: "line" }, svg);
    } else {
      xs.forEach((x, i) => {
        if (s.y[i] !== null) svgEl("circle", { cx: sx(x), cy: clampY(s.y[i]), r: 1.8,
          fill: s.color, class: "dot" }, svg);
      });
    }
  }
  for (const mk of marks) {
    if (mk.x < x0 || mk.x > x1) continue;
    const line = svgEl("line", { x1: sx(mk.x), x2: sx(mk.x), y1: m.t, y2: H - m.b,
      stroke: mk.color, "stroke-width": 2, "stroke-dasharray": "4 3", class: "alert-mark" }, svg);
    svgEl("title", {}, line).textContent = mk.title;
  }
}

async function loadDetail(name) {
  state.selected = name;
  // the id in the query: a browser rewrites the path segments "." and ".."
  const h = await api("/api/v1/history?component=" + encodeURIComponent(name));
  $("detail").hidden = false;
  $("detail-name").textContent = visible(name);
  $("detail-summary").textContent = h.n + " acquisitions (" + h.returned + " shown), " +
    h.alerts.length + " alerts";
  const H = h.history;
  const marks = h.alerts.map((a) => ({ x: a.time, color: a.level === "alarm" ? "#c00" : "#e80",
    title: a.level + " at " + fmt(a.time, 6) + (a.acknowledged ? " (acknowledged)" : "") }));
  chart($("hi-chart"), H.t, [
    { type: "dots", y: H.hi, color: "#888" }, { type: "line", y: H.fhi, color: "#0645ad" },
  ], marks);
  chart($("rul-chart"), H.t, [
    { type: "band", lo: H.rul_low, hi: H.rul_high, color: "#2a7" },
    { type: "line", y: H.rul, color: "#153" },
  ], marks, H.valid);
}

async function refresh() {
  if (!state.token) { setStatus("enter an API token (rulkit token create)"); return; }
  try {
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
  $("prev-page").addEventListener("click", () => {
    state.offset = Math.max(0, state.offset - state.limit); refresh();
  });
  $("next-page").addEventListener("click", () => { state.offset += state.limit; refresh(); });
  refresh();
});
