// balloon-gs web: the page. Read-only: it only listens (a WebSocket from the same server) and draws.
// Every message from the server is a "snapshot" (on connect: it replaces all the page holds, so a balloon the
// server does not know, after a restart, leaves the page) or an "update" (up to 10 a second); each holds every
// balloon's state; samples are [t (s, wall clock), speed m/s, from deg, accuracy m/s].
"use strict";

const TEN_MIN_S = 600, HOUR_S = 3600;
const CHART_EVERY_MS = 1000;      // the charts are redrawn at most this often (the numbers at every update)
const RECONNECT_MS = 1000;        // after the server went away, try again this often
const SILENT_SERVER_MS = 3000;    // no message for this long: the server is gone (or the network)
const SVGNS = "http://www.w3.org/2000/svg";
const BANNERS = {
  "STALE": (b, stale) => `STALE: no WIND_COV for ${Math.round(b.age_s)} s (link quiet > ${stale} s)`,
  "SENSORS LOST": () => "SENSORS LOST: the balloon hears none of its sensors; its wind is coasting",
  "MISFIT": (b) => `MODEL MISFIT (${b.misfit.join(", ")}): the model does not explain the data; accuracy grown`,
};

const balloons = new Map();       // sysid -> view
let ws = null, lastMessage = 0, staleS = 2, unknown = "—";

const fmt = (x, d) => (x === null || x === undefined || Number.isNaN(x)) ? unknown : x.toFixed(d);
const fmtSigned = (x, d) => (x === null || x === undefined) ? unknown : (x >= 0 ? "+" : "") + x.toFixed(d);
const fmtDir = (x) => (x === null || x === undefined) ? unknown : String(Math.round(x) % 360).padStart(3, "0");
const el = (tag, cls, text) => { const e = document.createElement(tag); if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text; return e; };

// ---------------------------------------------------------------- series kept in the page

class Series {
  constructor(keepS) { this.keepS = keepS; this.t = []; this.sp = []; this.fr = []; this.acc = []; }
  clear() { this.t.length = this.sp.length = this.fr.length = this.acc.length = 0; }
  push(rows) {
    const last = this.t.length ? this.t[this.t.length - 1] : -Infinity;
    for (const r of rows) {
      if (r[0] <= last) continue;   // already here (a snapshot and the update after it overlap)
      this.t.push(r[0]); this.sp.push(r[1]); this.fr.push(r[2]); this.acc.push(r[3]);
    }
  }
  trim(now) {
    let k = 0; while (k < this.t.length && this.t[k] <= now - this.keepS) k++;
    if (k) for (const a of [this.t, this.sp, this.fr, this.acc]) a.splice(0, k);
  }
  speedData() {
    const lo = this.sp.map((s, i) => s === null || this.acc[i] === null ? null : Math.max(0, s - this.acc[i]));
    const hi = this.sp.map((s, i) => s === null || this.acc[i] === null ? null : s + this.acc[i]);
    return [this.t, this.sp, lo, hi];
  }
  dirData() {
    const sig = this.sp.map((s, i) => s === null || this.acc[i] === null ? null :
      (s > 0 ? Math.min(180, this.acc[i] / s * 180 / Math.PI) : 180));
    const lo = this.fr.map((d, i) => d === null || sig[i] === null ? null : Math.max(0, d - sig[i]));
    const hi = this.fr.map((d, i) => d === null || sig[i] === null ? null : Math.min(360, d + sig[i]));
    return [this.t, this.fr, lo, hi];
  }
}

// ---------------------------------------------------------------- charts (uPlot)

function bandChart(target, label, unit, color, dir, time = true) {
  const opts = {
    width: Math.max(200, target.clientWidth), height: 170, legend: { show: false },
    scales: { x: { time }, y: dir ? { range: [0, 360] } : { range: (u, lo, hi) => [0, Math.max(1, hi * 1.1)] } },
    axes: [{}, { label: `${label} ${unit}`, size: 48, values: (u, v) => v.map((x) => x.toFixed(dir ? 0 : 1)),
                 splits: dir ? () => [0, 90, 180, 270, 360] : undefined }],
    series: [{},
      dir ? { stroke: color, width: 0, paths: () => null, points: { show: true, size: 3, fill: color, stroke: color } }
          : { stroke: color, width: 1.5 },
      { stroke: "transparent", width: 0, points: { show: false } },
      { stroke: "transparent", width: 0, points: { show: false } }],
    bands: [{ series: [3, 2], fill: dir ? "rgba(130,80,223,.15)" : "rgba(31,111,235,.15)" }],
  };
  return new uPlot(opts, [[], [], [], []], target);
}

function fitCharts(view) {
  for (const c of view.charts) c.setSize({ width: Math.max(200, c.root.parentElement.clientWidth), height: 170 });
}

// ---------------------------------------------------------------- the compass

function compass() {
  const s = document.createElementNS(SVGNS, "svg");
  s.setAttribute("viewBox", "-60 -60 120 120"); s.setAttribute("class", "compass");
  s.setAttribute("role", "img");
  s.innerHTML = `<circle r="50" fill="none" stroke="#bbb"/>` +
    ["N", "E", "S", "W"].map((c, i) => { const a = i * Math.PI / 2;
      return `<text x="${57 * Math.sin(a)}" y="${-55 * Math.cos(a) + 4}" text-anchor="middle" font-size="10">${c}</text>`; }).join("") +
    `<line class="mean" x1="0" y1="0" x2="0" y2="-46" visibility="hidden"/>` +
    `<line class="cur" x1="0" y1="0" x2="0" y2="-46" visibility="hidden"/><circle r="3"/>`;
  return s;
}

function needle(line, deg) {          // the needle points to where the wind comes FROM
  if (deg === null || deg === undefined) { line.setAttribute("visibility", "hidden"); return; }
  line.setAttribute("visibility", "visible");
  line.setAttribute("transform", `rotate(${deg})`);
}

// ---------------------------------------------------------------- the profile (SVG, error bars)

function profileSvg(legs, key, errKey, unit, fixedMax) {
  const W = 220, H = 200, L = 34, B = 24, T = 8, R = 8;
  const has = (r) => r[key] !== null && r[key] !== undefined;   // a bin without this value is a gap
  const rows = legs.flatMap((g) => g.rows);
  const zmax = Math.max(10, ...rows.map((r) => r.z)) * 1.05;
  const xmax = fixedMax || Math.max(1, ...rows.filter(has).map((r) => r[key] + (r[errKey] || 0))) * 1.05;
  const x = (v) => L + (W - L - R) * Math.min(Math.max(v, 0), xmax) / xmax;
  const y = (z) => H - B - (H - B - T) * z / zmax;
  const colors = ["#1f6feb", "#cf222e", "#1a7f37", "#8250df", "#9a6700", "#0a7ea4"];
  let s = `<svg viewBox="0 0 ${W} ${H}" xmlns="${SVGNS}">`;
  s += `<line class="axis" x1="${L}" y1="${H - B}" x2="${W - R}" y2="${H - B}"/><line class="axis" x1="${L}" y1="${T}" x2="${L}" y2="${H - B}"/>`;
  s += `<text x="${(L + W) / 2}" y="${H - 4}" text-anchor="middle">${unit}</text>`;
  s += `<text x="4" y="${T + 8}">m</text><text x="${L - 4}" y="${y(0)}" text-anchor="end">0</text>`;
  s += `<text x="${L - 4}" y="${y(zmax / 1.05) + 4}" text-anchor="end">${Math.round(zmax / 1.05)}</text>`;
  s += `<text x="${W - R}" y="${H - B + 12}" text-anchor="end">${Math.round(xmax)}</text>`;
  legs.forEach((g, k) => {
    const c = colors[k % colors.length];
    let run = [];                    // the line between bins with a value; broken at a gap
    const line = () => { if (run.length > 1) s += `<polyline points="${run.join(" ")}" fill="none" stroke="${c}" stroke-width="1" opacity=".6"/>`; run = []; };
    for (const r of g.rows) { if (has(r)) run.push(`${x(r[key]).toFixed(1)},${y(r.z).toFixed(1)}`); else line(); }
    line();
    for (const r of g.rows.filter(has)) {
      const e = r[errKey] || 0, yy = y(r.z).toFixed(1);
      s += `<line x1="${x(r[key] - e).toFixed(1)}" x2="${x(r[key] + e).toFixed(1)}" y1="${yy}" y2="${yy}" stroke="${c}"/>`;
      s += `<circle cx="${x(r[key]).toFixed(1)}" cy="${yy}" r="2.5" fill="${c}"><title>leg ${k + 1} (${g.ascent ? "up" : "down"}) ${r.z} m: ${r[key].toFixed(1)} ± ${e.toFixed(1)}</title></circle>`;
    }
  });
  return s + "</svg>";
}

function drawProfile(box, prof) {
  if (!prof || !prof.legs.length) { box.classList.add("hidden"); return; }
  box.classList.remove("hidden");
  const legs = prof.legs.filter((g) => g.rows.length);
  box.querySelector(".legs").textContent = prof.legs.map((g, k) => `leg ${k + 1} ${g.ascent ? "up" : "down"}`).join(", ") +
    ` (${prof.bin_m} m bins)`;
  box.querySelector(".p-speed").innerHTML = profileSvg(legs, "speed", "speed_err", "speed m/s");
  box.querySelector(".p-from").innerHTML = profileSvg(legs, "from", "from_err", "from °", 360);
}

// ---------------------------------------------------------------- one balloon's card

function card(sysid) {
  const c = el("article", "card"); c.dataset.sysid = sysid;
  c.innerHTML = `
    <div class="card-head"><h2>Balloon sys ${sysid}</h2><span class="state" data-k="state"></span></div>
    <div class="banner hidden" data-k="banner" role="alert"></div>
    <div class="now"><div class="cmp"></div><div>
      <div class="big"><span data-k="speed"></span> <small>m/s</small></div>
      <div>from <span class="big" data-k="from"></span><span class="big">°</span></div>
      <div class="dim">±<span data-k="acc"></span> m/s · alt <span data-k="alt"></span> m · <span data-k="mode"></span></div>
      <div class="dim">N <span data-k="n"></span> E <span data-k="e"></span> m/s · var <span data-k="var"></span> m/s</div>
    </div></div>
    <table class="kv">
      <tr><th>2-min mean</th><td data-k="m2"></td></tr>
      <tr><th>10-min mean</th><td data-k="m10"></td></tr>
      <tr><th>gust (3 s, 10 min)</th><td data-k="gust"></td></tr>
      <tr><th>filter</th><td data-k="filter"></td></tr>
      <tr><th>consistency</th><td data-k="consistency"></td></tr>
      <tr><th>link</th><td data-k="linkinfo"></td></tr>
    </table>
    <div class="said" data-k="said"></div>
    <div class="tabs" role="group" aria-label="chart window">
      <button type="button" data-w="600" aria-pressed="true">10 min</button>
      <button type="button" data-w="3600" aria-pressed="false">1 hour</button></div>
    <h3>speed (m/s, band ±accuracy)</h3><div class="chart c-speed"></div>
    <h3>direction from (°)</h3><div class="chart c-from"></div>
    <div class="profile hidden"><h3>profile: <span class="legs"></span></h3>
      <div class="pair"><div class="p-speed"></div><div class="p-from"></div></div></div>`;
  const view = { sysid, root: c, k: {}, short: new Series(TEN_MIN_S), hour: new Series(HOUR_S), window: TEN_MIN_S,
                 stats: null, lastChart: 0, charts: [] };
  c.querySelectorAll("[data-k]").forEach((e) => { view.k[e.dataset.k] = e; });
  const cmp = compass(); c.querySelector(".cmp").appendChild(cmp);
  view.cur = cmp.querySelector(".cur"); view.mean = cmp.querySelector(".mean");
  c.querySelectorAll(".tabs button").forEach((b) => b.addEventListener("click", () => {
    view.window = Number(b.dataset.w);
    c.querySelectorAll(".tabs button").forEach((o) => o.setAttribute("aria-pressed", String(o === b)));
    view.lastChart = 0; drawCharts(view, lastMessage / 1000);
  }));
  return view;
}

function ensureView(sysid) {
  let v = balloons.get(sysid);
  if (!v) {
    v = card(sysid);
    const main = document.getElementById("balloons");
    const after = [...main.querySelectorAll(".card")].find((e) => Number(e.dataset.sysid) > sysid);
    main.insertBefore(v.root, after || null);
    document.getElementById("waiting").classList.add("hidden");
    v.charts = [bandChart(v.root.querySelector(".c-speed"), "speed", "m/s", "#1f6feb", false),
                bandChart(v.root.querySelector(".c-from"), "from", "°", "#8250df", true)];
    v.resize = new ResizeObserver(() => fitCharts(v));
    v.resize.observe(v.root);
    balloons.set(sysid, v);
  }
  return v;
}

function dropView(v) {
  v.resize.disconnect();
  for (const c of v.charts) c.destroy();
  v.root.remove();
  balloons.delete(v.sysid);
}

function meanText(m, clock) {      // clock: the windows' ("balloon": WIND_COV time_usec, or "arrival")
  if (!m) return unknown;
  const by = clock === "balloon" ? "of flight (the balloon's clock)" : "as received";
  return `${fmt(m.speed, 2)} m/s from ${fmtDir(m.from)}° (${m.count} samples over ${Math.round(m.span_s)} s ${by})`;
}

function drawBalloon(v, b, now) {
  const k = v.k;
  const state = b.state;
  k.state.textContent = state === "STALE" ? `STALE ${Math.round(b.age_s)} s` : state;
  k.state.className = "state " + state.replace(" ", "-");
  v.root.classList.toggle("stale", state === "STALE");
  const banner = BANNERS[state];
  k.banner.classList.toggle("hidden", !banner);
  k.banner.classList.toggle("misfit", state === "MISFIT");
  k.banner.textContent = banner ? banner(b, staleS) : "";
  k.speed.textContent = fmt(b.speed, 2);
  k.from.textContent = fmtDir(b.from);
  k.acc.textContent = fmt(b.acc, 2);
  k.n.textContent = fmtSigned(b.n, 2);
  k.e.textContent = fmtSigned(b.e, 2);
  k.var.textContent = fmt(b.var, 2);
  k.alt.textContent = fmt(b.alt, 0);
  k.mode.textContent = `mode ${b.mode}`;
  if (b.stats) v.stats = b.stats;
  const st = v.stats || {};
  k.m2.textContent = meanText(st.mean_2min, st.clock);
  k.m10.textContent = meanText(st.mean_10min, st.clock);
  k.gust.textContent = st.gust === null || st.gust === undefined ? unknown : `${fmt(st.gust, 2)} m/s`;
  k.filter.textContent = `${b.mode}` + (b.estimator ? `; good: ${b.estimator.join(", ") || "none"}` : "") +
    (b.resets === null ? "" : `; ${b.resets} resets`);
  k.consistency.textContent = b.sensors_lost ? "sensors silent" : (b.misfit.length ? `flagged: ${b.misfit.join(", ")}` : "consistent");
  k.linkinfo.textContent = `${b.rate_hz} msg/s, ${b.link_lost} lost on the way` +
    (b.input_loss ? `; balloon input ${b.input_loss}` : "") + `; heartbeat ${b.hb_age_s === null ? "-" : Math.round(b.hb_age_s) + " s"} ago`;
  k.said.textContent = b.said ? `said: ${b.said}` : "";
  k.said.classList.toggle("warning", !!b.warning);
  needle(v.cur, b.from);
  needle(v.mean, st.mean_10min ? st.mean_10min.from : null);
  if (b.samples) v.short.push(b.samples);
  if (b.hour) v.hour.push(b.hour);
  if (b.profile) drawProfile(v.root.querySelector(".profile"), b.profile);
  v.short.trim(now); v.hour.trim(now);
  drawCharts(v, now);
}

function drawCharts(v, now) {
  const t = performance.now();
  if (t - v.lastChart < CHART_EVERY_MS) return;
  v.lastChart = t;
  const s = v.window === TEN_MIN_S ? v.short : v.hour;
  const [cs, cf] = v.charts;
  cs.setData(s.speedData(), false); cs.setScale("x", { min: now - v.window, max: now });
  cf.setData(s.dirData(), false); cf.setScale("x", { min: now - v.window, max: now });
}

// ---------------------------------------------------------------- messages

function onMessage(msg) {
  lastMessage = msg.t * 1000;
  staleS = msg.stale_s; unknown = msg.unknown;
  document.getElementById("stale-s").textContent = staleS;
  const L = msg.link;
  document.getElementById("link").textContent =
    `link: ${L.frames} frames, ${L.lost} lost, ${L.crc_errors} CRC errors, ${L.garbage_bytes} garbage bytes, ` +
    `${L.duplicates} duplicates`;
  document.getElementById("winch").textContent = msg.winch ?
    `winch: ${fmt(msg.winch.line_m, 1)} m out, reel ${fmt(msg.winch.reel_mps, 2)} m/s` : "";
  if (msg.type === "snapshot") {   // the server's state replaces the page's: a balloon it does not know leaves
    const known = new Set(msg.balloons.map((b) => b.sysid));
    for (const [sysid, v] of balloons) {
      if (!known.has(sysid)) { dropView(v); continue; }
      v.short.clear(); v.hour.clear(); v.lastChart = 0; v.stats = null;
    }
    document.getElementById("waiting").classList.toggle("hidden", balloons.size > 0 || msg.balloons.length > 0);
  }
  for (const b of msg.balloons) drawBalloon(ensureView(b.sysid), b, msg.t);
  if (msg.product && !document.getElementById("product").dataset.loaded) loadProduct();
}

function setConn(text, ok) {
  const c = document.getElementById("conn");
  c.textContent = text; c.className = "conn " + (ok ? "ok" : "bad");
  const pb = document.getElementById("page-banner");
  pb.classList.toggle("hidden", ok); pb.textContent = ok ? "" : `DISCONNECTED from the ground station: ${text}`;
}

let gotAt = 0;
function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(`${proto}//${location.host}/ws`);
  ws.onopen = () => { setConn("live", true); ws.send(JSON.stringify({ type: "hello" })); };
  ws.onmessage = (e) => { gotAt = performance.now(); onMessage(JSON.parse(e.data)); };
  ws.onclose = () => { setConn("reconnecting…", false); ws = null; setTimeout(connect, RECONNECT_MS); };
  ws.onerror = () => {};   // onclose follows and reconnects
}

setInterval(() => {             // a server that went quiet without closing (a network gone)
  if (ws && ws.readyState === WebSocket.OPEN && gotAt && performance.now() - gotAt > SILENT_SERVER_MS) {
    setConn("no message from the server", false); ws.close();
  }
}, 1000);

// ---------------------------------------------------------------- the product (balloon-gs reprocess)

async function loadProduct() {
  const box = document.getElementById("product");
  box.dataset.loaded = "1";
  const r = await fetch("/product/data.json");
  if (!r.ok) return;
  const p = await r.json();
  box.classList.remove("hidden");
  box.innerHTML = `<div class="card"><div class="card-head"><h2>Product: <a href="/product/${encodeURIComponent(p.name)}"></a></h2>
    <span class="dim">${p.points} estimates${p.step > 1 ? `, every ${p.step}th shown` : ""}</span></div>
    <p class="dim p-title"></p>
    <h3>speed (m/s): smoothed (zero-lag) and causal (real-time), bands ±1σ</h3><div class="chart pc-speed"></div>
    <h3>direction from (°)</h3><div class="chart pc-from"></div>
    <div class="profile hidden"><h3>profile: <span class="legs"></span></h3><div class="pair"><div class="p-speed"></div><div class="p-from"></div></div></div></div>`;
  box.querySelector("a").textContent = p.name;
  box.querySelector(".p-title").textContent = p.title;
  // a UTC product (its units say so) in UTC; a sensor clock's (no absolute time) as seconds since the boot
  const timeLabel = p.utc ? "time (UTC)" : "s since boot (sensor clock, not UTC)";
  const band = (v, e, cap) => [v.map((x, i) => x === null || e[i] === null ? null : Math.max(0, x - e[i])),
                               v.map((x, i) => x === null || e[i] === null ? null : (cap ? Math.min(cap, x + e[i]) : x + e[i]))];
  const chart = (target, key, dir) => {
    const [slo, shi] = band(p[key], p[key + "_err"], dir ? 360 : 0);
    const [clo, chi] = band(p["causal_" + key], p["causal_" + key + "_err"], dir ? 360 : 0);
    const pts = (c) => dir ? { stroke: c, width: 0, paths: () => null, points: { show: true, size: 2, fill: c } } : { stroke: c, width: 1.2 };
    const hide = { stroke: "transparent", width: 0, points: { show: false } };
    return new uPlot({ width: Math.max(200, target.clientWidth), height: 200, scales: { x: { time: p.utc }, y: dir ? { range: [0, 360] } : {} },
      ...(p.utc ? { tzDate: (ts) => uPlot.tzDate(new Date(ts * 1e3), "Etc/UTC") } : {}),   // UTC, not the browser's zone
      legend: { show: true }, axes: [{ label: timeLabel }, { size: 48 }],
      series: [{ label: timeLabel }, { label: "smoothed", ...pts("#1f6feb") }, { label: "causal", ...pts("#cf222e") }, hide, hide, hide, hide],
      bands: [{ series: [4, 3], fill: "rgba(31,111,235,.15)" }, { series: [6, 5], fill: "rgba(207,34,46,.12)" }] },
      [p.time, p[key], p["causal_" + key], slo, shi, clo, chi], target);
  };
  const charts = [chart(box.querySelector(".pc-speed"), "speed", false), chart(box.querySelector(".pc-from"), "from", true)];
  new ResizeObserver(() => charts.forEach((c) => c.setSize({ width: Math.max(200, c.root.parentElement.clientWidth), height: 200 }))).observe(box);
  if (p.profile) drawProfile(box.querySelector(".profile"), p.profile);
}

connect();
