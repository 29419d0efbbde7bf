// The operator's page: everything comes pushed over /events (server-sent events); the page
// only reads. Frame age = the appliance's clock now - the shown picture's capture time; the
// appliance's clock is estimated from the send times of the messages (the largest of
// "sent - received" over the last messages: at most the network delay too young).
"use strict";
const $ = (id) => document.querySelector(`[data-testid="${id}"]`);
const offsets = [];          // appliance clock - local clock, ms, of the last messages
let shown = null;            // notice of the picture on screen
let pending = null;          // newest notice not yet loaded
let loading = false;
let lastMessage = 0;
let connected = false;

function noteClock(sentNs) {
  if (!sentNs) return;
  offsets.push(sentNs / 1e6 - Date.now());
  if (offsets.length > 30) offsets.shift();
}
const applianceNowS = () => (Date.now() + Math.max(...offsets, -Infinity)) / 1000;
const fmtTime = (tS) => tS == null ? "-" : new Date(tS * 1000).toLocaleTimeString();
const fmtDate = (tS) => tS == null ? "-" : new Date(tS * 1000).toLocaleString();
const num = (v, d) => (v == null || !isFinite(v)) ? "-" : Number(v).toFixed(d);

function duration(s) {
  s = Math.max(0, Math.round(s));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${s % 60} s`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
}

const FLAG_WORDS = {
  line_of_sight: "weak: the gas moves mostly along the line of sight",
  single_camera: "one camera only: no stereo depth, the rate is less certain",
};

function renderStatus(s) {
  const leak = s.leak || {};
  const open = leak.state === "LEAK";
  $("leak-state").textContent = open ? "LEAK" : "NO LEAK";
  $("leak-since").textContent = open && leak.since_t_s != null
    ? `since ${fmtTime(leak.since_t_s)} (${duration(leak.for_s || 0)})` : "";
  document.getElementById("banner").className = open ? "leak" : "noleak";
  const src = open && leak.event ? leak.event.source_xy : null;
  const mark = document.getElementById("source");
  mark.setAttribute("cx", src ? src[0] : -50);
  mark.setAttribute("cy", src ? src[1] : -50);

  const r = s.rate || {};
  $("rate").textContent = r.kg_h == null ? "not measurable now"
    : `${num(r.kg_h, 2)}${r.uncertainty_kg_h == null ? "" : " \u00b1 " + num(r.uncertainty_kg_h, 2)} kg/h`;
  $("rate-flags").textContent = (r.flags || []).map((f) => FLAG_WORDS[f] || f).join("; ");
  $("rate-flags").className = (r.flags || []).length ? "warn" : "";
  $("true-rate").textContent = r.true_kg_h == null ? ""
    : `simulation: true release ${num(r.true_kg_h, 2)} kg/h`;

  const w = s.wind || {};
  $("wind").textContent = (w.words || "-").replace(/^wind: /, "");
  const v = w.vector_m_s, line = document.getElementById("wind-arrow");
  const sp = v ? Math.hypot(v[0], v[1]) : 0;
  line.setAttribute("x2", sp > 0 ? 0.85 * v[0] / sp : 0);
  line.setAttribute("y2", sp > 0 ? 0.85 * v[1] / sp : 0);

  renderHealth(s.health || {});
  renderEvents(s.events || []);
}

function renderHealth(h) {
  const ul = $("health");
  const words = h.words && h.words.length ? h.words : ["starting"];
  const fine = words.findIndex((x) => x === "all devices delivering" || /GB free for/.test(x) ||
    /^offset steps levelled/.test(x));
  ul.replaceChildren(...words.map((x, i) => {
    const li = document.createElement("li");
    li.textContent = x;
    if (fine < 0 || i < fine) li.className = "problem";
    return li;
  }));
  // Every stream the health monitor reports, with every field it has.
  const streams = (h.snapshot && h.snapshot.streams) || {};
  const table = $("streams");
  const rows = Object.entries(streams).map(([name, st]) => {
    const tr = document.createElement("tr");
    const cells = [name, ...Object.entries(st).map(([k, val]) =>
      `${k} ${typeof val === "number" ? num(val, Number.isInteger(val) ? 0 : 1) : val}`)];
    tr.replaceChildren(...cells.map((c) => {
      const td = document.createElement("td");
      td.textContent = c;
      return td;
    }));
    return tr;
  });
  table.replaceChildren(...rows);
}

function renderEvents(events) {
  const body = $("events").querySelector("tbody");
  body.replaceChildren(...events.map((e) => {
    const tr = document.createElement("tr");
    const end = e.end_t_s;
    const cells = [e.id, fmtDate(e.start_t_s),
      end == null ? "ongoing" : duration(end - e.start_t_s),
      e.peak_rate_g_s == null ? "-" : num(e.peak_rate_g_s * 3.6, 2),
      e.end_reason || (end == null ? "-" : ""), e.clip || "-"];
    tr.replaceChildren(...cells.map((c, i) => {
      const td = document.createElement("td");
      td.textContent = c;
      if (i === 5) td.className = "clip";
      return td;
    }));
    return tr;
  }));
}

function wantFrame(f) {
  pending = f;
  if (!loading) loadNext();
}

function loadNext() {
  if (!pending) return;
  const f = pending;
  pending = null;
  loading = true;
  const img = new Image();
  img.alt = "newest left IR picture with the gas overlay";
  img.onload = () => { showFrame(img, f); loading = false; loadNext(); };
  img.onerror = () => { loading = false; loadNext(); };  // gone already: the next one
  img.src = f.url;
}

function showFrame(img, f) {
  const old = $("picture");
  img.dataset.testid = "picture";
  img.dataset.captureNs = String(f.t_capture_ns);
  img.dataset.seq = String(f.seq);
  img.dataset.resultNs = String(f.t_result_ns);
  img.dataset.overlayNs = f.overlay_capture_ns == null ? "" : String(f.overlay_capture_ns);
  old.replaceWith(img);
  document.getElementById("overlay").setAttribute("viewBox", `0 0 ${f.width} ${f.height}`);
  $("frame-number").textContent = f.frame;
  // The overlay is the newest processed result's: say how much older than the picture it is.
  $("overlay-age").textContent = f.overlay_capture_ns == null ? "no recent gas result"
    : `gas overlay ${((f.t_capture_ns - f.overlay_capture_ns) / 1e9).toFixed(2)} s older`;
  shown = f;
  tick();
}

function tick() {
  const age = $("frame-age");
  if (shown && offsets.length) {
    age.textContent = (applianceNowS() - shown.t_capture_ns / 1e9).toFixed(2);
  }
  const silent = (Date.now() - lastMessage) / 1000;
  const link = $("connection");
  if (!connected || silent > 5) {
    link.textContent = connected ? `no update for ${Math.round(silent)} s` : "connection lost; retrying";
    document.getElementById("banner").className = "stale";
  } else {
    link.textContent = `live \u00b7 ${new Date(applianceNowS() * 1000).toLocaleTimeString()}`;
  }
}

function connect() {
  const es = new EventSource("/events");
  es.onopen = () => { connected = true; lastMessage = Date.now(); };
  es.onerror = () => { connected = false; tick(); };
  es.addEventListener("status", (e) => {
    const s = JSON.parse(e.data);
    lastMessage = Date.now();
    noteClock(s.sent_ns);
    renderStatus(s);
    tick();
  });
  es.addEventListener("frame", (e) => {
    const f = JSON.parse(e.data);
    lastMessage = Date.now();
    noteClock(f.sent_ns);
    wantFrame(f);
  });
}

connect();
setInterval(tick, 100);
