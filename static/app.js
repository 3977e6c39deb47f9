// aar-dock operators' page: vanilla JS, no external assets.
"use strict";

const API = "/api/v1";
const $ = (id) => document.getElementById(id);
const LED_COLORS = ["#e63c3c", "#f0aa28", "#3cc85a", "#328cf0", "#be50e6"];
const CHART_WINDOW_S = 10;
// The telemetry WebSocket lives in a worker (static/telemetry_worker.js), off this page's main
// thread, which a 3-D view drawn in software (no GPU) keeps busy: the page pulls the newest
// state from it at most RENDER_HZ times a second, one request at a time, so messages never
// queue up here (they did: with the 3-D view embedded the numbers lagged seconds behind).
const RENDER_HZ = 10;
const STALE_S = 2.0; // telemetry older than this: "lagging" in the connection badge
let serviceConfig = null;
let latest = null;
let shownSeq = -1; // the worker's message count at the last redraw
let pulling = false; // a snapshot request is in flight
let simRunning = null; // from /healthz: false → the banner says STOPPED
let lastMiss = null; // {miss, captured, run}: the last plane crossing's miss (set on one tick)
let lastContact = null; // {peak, run}: the hose's peak tension of the last latched contact (N)
let lastOutcome = null; // {outcome, run}: the last run's outcome class (set on its last tick)
let series = []; // {t, y, z, lat} of the current run only (from the worker)
let connState = "connecting";
let telemetry = null; // the worker

function authHeaders() {
  const tok = $("token").value.trim();
  return tok ? { Authorization: "Bearer " + tok } : {};
}

async function api(method, path, body) {
  const opts = { method, headers: authHeaders() };
  if (body !== undefined) {
    if (body instanceof FormData) {
      opts.body = body;
    } else {
      opts.headers["Content-Type"] = "application/json";
      opts.body = JSON.stringify(body);
    }
  }
  const r = await fetch(API + path, opts);
  let data = null;
  try { data = await r.json(); } catch (e) { data = null; }
  if (!r.ok) {
    let detail = data && data.detail !== undefined ? data.detail : r.statusText;
    if (Array.isArray(detail)) detail = detail.map((d) => (d.loc || []).slice(1).join(".") + ": " + d.msg).join("; ");
    throw new Error(r.status + " " + detail);
  }
  return data;
}

const fmt = (v, d = 2) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(d));

// ---- telemetry ---------------------------------------------------------------------------
function connectTelemetry() {
  const proto = location.protocol === "https:" ? "wss://" : "ws://";
  telemetry = new Worker("/static/telemetry_worker.js");
  telemetry.onmessage = (ev) => {
    pulling = false;
    const snap = ev.data;
    connState = snap.conn;
    if (snap.series !== null) series = snap.series;
    const changed = snap.seq !== shownSeq;
    shownSeq = snap.seq;
    latest = snap.latest;
    lastMiss = snap.lastMiss;
    lastOutcome = snap.lastOutcome;
    lastContact = snap.lastContact;
    render(changed);
  };
  telemetry.postMessage({ type: "connect", url: proto + location.host + API + "/telemetry" });
}

function pullTelemetry() {
  if (telemetry === null || pulling) return; // one request in flight: nothing queues up
  pulling = true;
  telemetry.postMessage({ type: "snapshot", since: shownSeq });
}

// the run-time assurance: while its recovery law flies (the record's rta_reason), a banner
// saying why — RECOVERY (red) for an envelope recovery, BREAK-AWAY (amber) otherwise
function renderRta(rec) {
  const rta = $("rta");
  const reason = rec && rec.source === "sim" && simRunning !== false ? rec.rta_reason : null;
  rta.hidden = !reason;
  if (!reason) { rta.textContent = ""; rta.className = "rta"; return; }
  const envelope = reason.startsWith("envelope:");
  rta.textContent = (envelope ? "RECOVERY — " : "BREAK-AWAY — ") + reason;
  rta.className = "rta " + (envelope ? "recovery" : "breakaway");
}

function renderBanner() {
  const rec = latest;
  const lock = $("lock");
  renderRta(rec);
  // stopped: STOPPED over the last sim tick or the last upload (an upload in the 3 s before a
  // finished run restarts would otherwise keep its lock on the banner for good)
  if (simRunning === false && (!rec || rec.source === "sim" || rec.source === "upload")) {
    lock.textContent = "STOPPED";
    lock.className = "lock stopped";
    $("lock-reason").textContent = "simulation stopped (Start to resume)";
    return;
  }
  if (!rec) return;
  lock.textContent = rec.lock ? "LOCK" : "NO LOCK";
  lock.className = "lock " + (rec.lock ? "on" : "off");
  $("lock-reason").textContent = rec.lock ? "" : (rec.lock_reason || "");
}

function renderLag() {
  const conn = $("conn");
  conn.dataset.state = connState;
  if (connState !== "live") {
    conn.textContent = connState === "closed" ? "reconnecting…" : "connecting…";
    conn.className = "conn";
    return;
  }
  if (!latest) { conn.textContent = "live"; return; }
  const lag = Date.now() / 1000 - latest.wall_time;
  const stale = simRunning !== false && latest.source === "sim" && lag > STALE_S;
  conn.textContent = stale ? "lagging " + lag.toFixed(1) + " s" : "live";
  conn.className = "conn" + (stale ? " warn" : "");
}

function render(changed) {
  renderLag();
  if (!changed) return;
  const rec = latest;
  if (!rec) return;
  renderBanner();
  $("source").textContent = rec.source + " / " + rec.run;
  $("t_s").textContent = fmt(rec.t_s, 2);
  $("phase").textContent = rec.phase || "–";
  $("captured").textContent = rec.captured === null || rec.captured === undefined ? "–" : (rec.captured ? "yes" : "no");
  // the outcome is set on a run's last tick only: show the last run's that ended
  $("run-outcome").textContent = lastOutcome ? lastOutcome.outcome + " (run " + lastOutcome.run + ")" : "–";
  // the multi-body hose's peak tension over the last latched contact (kept while it rides)
  $("contact-peak").textContent = lastContact ? fmt(lastContact.peak, 0) + " N (run " + lastContact.run + ")" : "–";
  const r = rec.rel_position_m;
  $("rel-x").textContent = r ? fmt(r[0], 3) : "–";
  $("rel-y").textContent = r ? fmt(r[1], 3) : "–";
  $("rel-z").textContent = r ? fmt(r[2], 3) : "–";
  $("lateral").textContent = r ? fmt(Math.hypot(r[1], r[2]), 3) : "–";
  const c = rec.control;
  for (const k of ["throttle", "aileron", "elevator", "rudder"]) $("c-" + k).textContent = c ? fmt(c[k], 4) : "–";
  $("nleds").textContent = rec.pose ? rec.pose.leds.length : "–";
  const dro = rec.pose && rec.pose.lock ? rec.pose.drogue : null;
  $("pl").textContent = dro && dro.protection_level_mm != null ? fmt(dro.protection_level_mm, 2) : "–";
  $("chi2").textContent = dro && dro.fit_chi2 != null ? fmt(dro.fit_chi2, 1) + " / " + dro.fit_dof : "–";
  // the miss is set on the one tick that crosses the drogue plane: show the last crossing's
  $("miss").textContent = lastMiss ? fmt(lastMiss.miss, 3) + (lastMiss.captured ? " ✓" : " ✗") : "–";
  $("miss").title = lastMiss ? "last drogue-plane crossing: run " + lastMiss.run + (lastMiss.captured ? ", captured" : ", missed") : "";
  $("step-ms").textContent = fmt(rec.timings_ms.step, 1);
  $("vision-ms").textContent = fmt(rec.timings_ms.total, 1);
  drawChart();
}

function drawChart() {
  const cv = $("chart");
  const w = cv.clientWidth || cv.width, h = cv.clientHeight || cv.height;
  if (cv.width !== w) cv.width = w;
  if (cv.height !== h) cv.height = h;
  const g = cv.getContext("2d");
  g.clearRect(0, 0, w, h);
  if (series.length < 2) return;
  const t1 = series[series.length - 1].t, t0 = Math.max(series[0].t, t1 - CHART_WINDOW_S);
  let lo = -0.4, hi = 0.4;
  for (const p of series) { lo = Math.min(lo, p.y, p.z); hi = Math.max(hi, p.y, p.z, p.lat); }
  const pad = 26;
  const X = (t) => pad + ((t - t0) / Math.max(1e-6, t1 - t0)) * (w - pad - 6);
  const Y = (v) => 6 + (1 - (v - lo) / (hi - lo)) * (h - 20);
  g.strokeStyle = "#ddd"; g.lineWidth = 1;
  g.beginPath(); g.moveTo(pad, Y(0)); g.lineTo(w - 6, Y(0)); g.stroke();
  g.fillStyle = "#888"; g.font = "10px sans-serif";
  g.fillText(hi.toFixed(2), 2, 12); g.fillText(lo.toFixed(2), 2, h - 8);
  const cap = 0.305;
  g.setLineDash([4, 4]); g.strokeStyle = "#999";
  g.beginPath(); g.moveTo(pad, Y(cap)); g.lineTo(w - 6, Y(cap)); g.stroke();
  g.setLineDash([]);
  const line = (key, color) => {
    g.strokeStyle = color; g.lineWidth = 1.6; g.beginPath();
    series.forEach((p, i) => (i ? g.lineTo(X(p.t), Y(p[key])) : g.moveTo(X(p.t), Y(p[key]))));
    g.stroke();
  };
  line("y", "#2f9a4f"); line("z", "#2f6fdf"); line("lat", "#d23a3a");
}

async function pollHealth() {
  try {
    const h = await api("GET", "/healthz");
    $("tick-rate").textContent = fmt(h.tick_rate_hz, 1);
    $("dropped").textContent = h.dropped_ticks;
    if (h.drogue) $("drogue").textContent = h.drogue.label;
    // degraded: which part and why (a stream that failed and restarts, a stopped tick loop)
    const bad = (h.components || []).filter((c) => c.status !== "ok");
    const health = $("health");
    health.hidden = bad.length === 0;
    health.textContent = bad.length ? "DEGRADED — " + bad.map((c) => c.name + ": " + (c.reason || "")).join("; ") : "";
    if (simRunning !== h.sim_running) { simRunning = h.sim_running; renderBanner(); }
  } catch (e) { /* server restarting */ }
}

// ---- simulation controls -------------------------------------------------------------------
function fillSimForm(cfg) {
  $("plant").value = cfg.plant;
  $("turbulence").value = cfg.turbulence;
  $("closure").value = cfg.closure_speed_mps;
  $("noise").value = cfg.noise_sigma;
  $("clutter").value = cfg.clutter;
  $("seed").value = cfg.seed;
  document.querySelectorAll(".drop").forEach((cb) => { cb.checked = cfg.led_dropout.includes(Number(cb.value)); });
}

// the simulated receiver: airframe and flight condition (trim) of the configured plant
function showPlant(status) {
  const p = status && status.plant;
  if (!p) { $("airframe").textContent = "plant: unavailable"; return; }
  const t = p.trim;
  $("airframe").textContent = `${p.airframe} · ${fmt(t.altitude_ft, 0)} ft · ${fmt(t.kcas, 0)} KCAS ` +
    `(${fmt(t.tas_mps, 1)} m/s TAS) · α ${fmt(t.alpha_deg, 2)}° · throttle ${fmt(t.throttle, 3)} · ${fmt(t.weight_lbs, 0)} lb`;
}

function simMsg(text, err) { const m = $("sim-msg"); m.textContent = text; m.className = "msg" + (err ? " err" : ""); }

function wireControls() {
  for (const [id, path] of [["btn-start", "/sim/start"], ["btn-stop", "/sim/stop"], ["btn-reset", "/sim/reset"]]) {
    $(id).addEventListener("click", async () => {
      try {
        const s = await api("POST", path);
        simMsg((s.running ? "running" : "stopped") + ", run " + s.run);
        simRunning = s.running; renderBanner();
      }
      catch (e) { simMsg(e.message, true); }
    });
  }
  $("sim-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const body = {
      plant: $("plant").value,
      turbulence: $("turbulence").value,
      closure_speed_mps: Number($("closure").value),
      noise_sigma: Number($("noise").value),
      clutter: Number($("clutter").value),
      seed: Number($("seed").value),
      led_dropout: [...document.querySelectorAll(".drop")].filter((c) => c.checked).map((c) => Number(c.value)),
    };
    try { fillSimForm(await api("PUT", "/sim/config", body)); simMsg("applied (new run)"); showPlant(await api("GET", "/sim")); }
    catch (e) { simMsg(e.message, true); }
  });
}

// ---- cameras: the service draws the detections (GET /camera/{side}.jpg), the page shows them
const CAMERA_HZ = 3;
let cameraSeq = -1; // the telemetry seq of the images on screen
let cameraBusy = false;

async function fetchCamera(side, source) {
  const r = await fetch(API + "/camera/" + side + ".jpg?source=" + source, { cache: "no-store" });
  if (!r.ok) return null;
  return { blob: await r.blob(), seq: Number(r.headers.get("X-Seq")), ids: r.headers.get("X-Led-Ids") || "", lock: r.headers.get("X-Lock") === "1", rejected: Number(r.headers.get("X-Rejected") || 0) };
}

function showCamera(img, cap, side, got) {
  const old = img.dataset.url;
  img.dataset.url = URL.createObjectURL(got.blob);
  img.src = img.dataset.url;
  img.dataset.seq = String(got.seq);
  if (old) URL.revokeObjectURL(old);
  cap.textContent = side + " · #" + got.seq + " · " + (got.lock ? "LOCK" : "NO LOCK") + " · LEDs " + (got.ids ? got.ids.split(",").join(" ") : "none") + (got.rejected ? " · rejected " + got.rejected : "");
  cap.dataset.ids = got.ids;
}

async function refreshCameras() {
  if (cameraBusy || document.hidden || !latest || latest.seq === cameraSeq || latest.source === "upload") return;
  cameraBusy = true;
  try {
    const [l, r] = await Promise.all([fetchCamera("left", "live"), fetchCamera("right", "live")]);
    if (l) showCamera($("cam-left"), $("cam-left-cap"), "left", l);
    if (r) showCamera($("cam-right"), $("cam-right-cap"), "right", r);
    if (l) cameraSeq = latest.seq;
  } catch (e) { /* the next round retries */ } finally { cameraBusy = false; }
}

// ---- upload ---------------------------------------------------------------------------------
function loadImage(file) {
  return new Promise((resolve) => {
    const url = URL.createObjectURL(file);
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => resolve(null); // e.g. TIFF: browsers cannot show it; draw detections only
    img.src = url;
  });
}

function drawPair(canvas, img, leds, key, size) {
  const g = canvas.getContext("2d");
  const [W, H] = size;
  const s = canvas.width / W;
  canvas.height = Math.round(H * s);
  g.fillStyle = "#000"; g.fillRect(0, 0, canvas.width, canvas.height);
  if (img) g.drawImage(img, 0, 0, canvas.width, canvas.height);
  g.lineWidth = 2; g.font = "bold 13px sans-serif";
  for (const led of leds) {
    const [u, v] = led[key];
    const col = LED_COLORS[(led.id - 1) % LED_COLORS.length];
    g.strokeStyle = col; g.fillStyle = col;
    g.beginPath(); g.arc(u * s, v * s, 9, 0, 2 * Math.PI); g.stroke();
    g.fillText(String(led.id), u * s + 11, v * s - 7);
  }
}

async function drawServed(canvas, got) {
  const bmp = await createImageBitmap(got.blob);
  canvas.width = bmp.width; canvas.height = bmp.height;
  canvas.getContext("2d").drawImage(bmp, 0, 0);
  canvas.dataset.ids = got.ids;
}

function clearUploadResult() {
  $("upload-result").hidden = true;
  $("upload").dataset.state = "pending";
  $("upload-summary").textContent = "";
  document.querySelector("#led-table tbody").innerHTML = "";
  for (const id of ["upload-left", "upload-right"]) {
    const c = $(id);
    c.getContext("2d").clearRect(0, 0, c.width, c.height);
  }
}

function wireUpload() {
  $("upload-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const form = new FormData(ev.target);
    const st = $("upload-status");
    clearUploadResult(); // never leave the previous pair's result under a new request
    st.textContent = "processing…"; st.className = "msg";
    try {
      const res = await api("POST", "/stereo", form);
      // the service's drawing of this pair (the same as the live cameras'); the page's own
      // drawing on the browser-decoded files only where the service has no image to give
      const [ls, rs] = await Promise.all([fetchCamera("left", "upload"), fetchCamera("right", "upload")]);
      if (ls && rs) {
        await Promise.all([drawServed($("upload-left"), ls), drawServed($("upload-right"), rs)]);
      } else {
        const [li, ri] = await Promise.all([loadImage($("left-file").files[0]), loadImage($("right-file").files[0])]);
        const size = serviceConfig ? serviceConfig.image_size : [li ? li.naturalWidth : 1280, li ? li.naturalHeight : 1024];
        drawPair($("upload-left"), li, res.leds, "left_px", size);
        drawPair($("upload-right"), ri, res.leds, "right_px", size);
      }
      const tb = document.querySelector("#led-table tbody");
      tb.innerHTML = "";
      for (const led of res.leds) {
        const tr = document.createElement("tr");
        const cells = [led.id, fmt(led.left_px[0], 1) + ", " + fmt(led.left_px[1], 1), fmt(led.right_px[0], 1) + ", " + fmt(led.right_px[1], 1),
          fmt(led.xyz_mm[0], 2), fmt(led.xyz_mm[1], 2), fmt(led.xyz_mm[2], 2), fmt(led.epipolar_px, 3), fmt(led.reprojection_px, 3)];
        for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
        tr.firstChild.style.color = LED_COLORS[(led.id - 1) % LED_COLORS.length];
        tb.appendChild(tr);
      }
      let summary = (res.lock ? "LOCK" : "NO LOCK" + (res.reason ? " (" + res.reason + ")" : "")) + " — " + res.leds.length + " LEDs matched";
      if (res.drogue) {
        const d = res.drogue;
        summary += "; drogue centre (" + d.center_mm.map((v) => fmt(v, 1)).join(", ") + ") mm, normal (" +
          d.normal.map((v) => fmt(v, 3)).join(", ") + "), radius " + fmt(d.radius_mm, 1) + " mm, rms " + fmt(d.rms_mm, 2) + " mm" +
          (d.protection_level_mm != null ? ", error < " + fmt(d.protection_level_mm, 2) + " mm (99.9 %)" : "");
      }
      summary += "; pipeline " + fmt(res.timing_ms.total, 1) + " ms";
      $("upload-summary").textContent = summary;
      $("upload-result").hidden = false;
      $("upload").dataset.state = "done";
      st.textContent = "done";
    } catch (e) {
      clearUploadResult();
      $("upload").dataset.state = "failed";
      st.textContent = "failed: " + e.message; st.className = "msg err";
    }
  });
}

// ---- recordings -----------------------------------------------------------------------------
async function refreshRecordings() {
  try {
    const recs = await api("GET", "/recordings");
    const ul = $("rec-list");
    ul.innerHTML = "";
    for (const r of recs) {
      const li = document.createElement("li");
      const when = new Date(r.started_wall * 1000).toLocaleString();
      li.textContent = r.id + " — " + when + ", " + r.ticks + " ticks"
        + (r.frame_pairs ? ", " + r.frame_pairs + " pairs, " + (r.frames_bytes / 1e6).toFixed(0) + " MB (" + (r.frames_encoding || "png") + ")" : "")
        + (r.stop_reason && !r.active ? " — " + r.stop_reason : "")
        + (r.active ? " (recording…)" : "") + " ";
      if (!r.active) {
        const base = API + "/recordings/" + encodeURIComponent(r.id);
        const links = [["telemetry (JSONL)", base + "/telemetry.jsonl"]];
        if (r.scene_file) {
          links.push(["scene (.viser)", base + "/scene.viser"]);
          links.push(["replay 3-D", "/viser-client/?playbackPath=" + encodeURIComponent(base + "/scene.viser")]);
        }
        for (const [label, href] of links) {
          const a = document.createElement("a"); a.href = href; a.textContent = label; a.target = "_blank";
          li.appendChild(a); li.appendChild(document.createTextNode(" "));
        }
      }
      ul.appendChild(li);
    }
  } catch (e) { /* ignore */ }
}

/** The recording options chosen on the page, as a query string. */
function recordingQuery() {
  const q = new URLSearchParams({
    frames: $("rec-frames").checked ? "true" : "false",
    codec: $("rec-codec").value,
    png_level: $("rec-png-level").value || "1",
    jpeg_quality: $("rec-jpeg-quality").value || "90",
  });
  return "?" + q.toString();
}

function minSec(s) {
  if (s === null || s === undefined) return "–";
  const m = Math.floor(s / 60), r = Math.round(s - 60 * m);
  return m > 0 ? m + " min " + r + " s" : r + " s";
}

const BOUND_TEXT = {
  "max_s": "the time limit (AAR_RECORDING_MAX_S)",
  "frames budget": "the frames' budget (AAR_RECORDING_FRAMES_MAX_MB)",
  "size bound": "the telemetry's size bound (AAR_RECORDING_MAX_MB)",
  "free space": "the free disk space above the floor (AAR_RECORDING_MIN_FREE_MB)",
};

/** The write rate and the time left (recording), or how long one can run (before a start). */
async function refreshRecordingBudget() {
  const el = $("rec-budget");
  if (!el) return;
  try {
    const p = await api("GET", "/recording" + recordingQuery());
    const rate = p.mb_per_min === null ? "–" : p.mb_per_min.toFixed(0) + " MB/min";
    const by = p.limited_by ? ", limited by " + (BOUND_TEXT[p.limited_by] || p.limited_by) : "";
    const what = p.frames ? "frames " + p.encoding + (p.lossless ? "" : " — lossy") : "telemetry only";
    let text;
    if (p.active) {
      text = "recording (" + what + "): " + rate + " measured, " + minSec(p.time_left_s) + " left" + by;
    } else if (p.time_left_s === null) {
      text = "a recording (" + what + "): no estimate yet (" + p.basis + ")";
    } else {
      text = "a recording (" + what + ") can run ≈ " + minSec(p.time_left_s) + " at ≈ " + rate + by + " (from " + p.basis + ")";
    }
    el.textContent = text;
    el.dataset.timeLeft = p.time_left_s === null ? "" : String(p.time_left_s);
    el.dataset.active = String(p.active);
  } catch (e) { el.textContent = "recording budget: " + e.message; }
}

function wireRecordings() {
  for (const id of ["rec-frames", "rec-codec", "rec-png-level", "rec-jpeg-quality"]) {
    $(id).addEventListener("change", refreshRecordingBudget);
  }
  $("rec-start").addEventListener("click", async () => {
    try { const r = await api("POST", "/recording/start" + recordingQuery()); $("rec-msg").textContent = "recording " + r.id; }
    catch (e) { $("rec-msg").textContent = e.message; }
    refreshRecordings();
  });
  $("rec-stop").addEventListener("click", async () => {
    try { const r = await api("POST", "/recording/stop"); $("rec-msg").textContent = "saved " + r.id + " (" + r.ticks + " ticks)"; }
    catch (e) { $("rec-msg").textContent = e.message; }
    refreshRecordings();
  });
}

/** Is WebGL drawn by the CPU here (SwiftShader, llvmpipe: no GPU, e.g. headless chromium)? */
function softwareWebGL() {
  try {
    const gl = document.createElement("canvas").getContext("webgl");
    if (!gl) return true;
    const ext = gl.getExtension("WEBGL_debug_renderer_info");
    const name = ext ? String(gl.getParameter(ext.UNMASKED_RENDERER_WEBGL)) : "";
    return /swiftshader|llvmpipe|software|softpipe/i.test(name);
  } catch (e) { return true; }
}

// ---- start ----------------------------------------------------------------------------------
async function init() {
  wireControls(); wireUpload(); wireRecordings();
  try {
    serviceConfig = await api("GET", "/config");
    if (serviceConfig.token_required) $("token-row").hidden = false;
    if (serviceConfig.viser_port) {
      let url = serviceConfig.viser_url || (location.protocol + "//" + location.hostname + ":" + serviceConfig.viser_port + "/");
      // "index.html": viser then knows this is the embedded view (its control panel starts
      // minimized there; the camera is framed on the docking for every view)
      url = url.split("?")[0].replace(/\/?$/, "/") + "index.html";
      if (softwareWebGL()) {
        // no GPU: render the 3-D view at half resolution (a quarter of the pixels to shade)
        url += (url.includes("?") ? "&" : "?") + "fixedDpr=0.5";
        $("viser-note").hidden = false;
      }
      $("viser-frame").src = url;
    } else {
      $("viser-missing").hidden = false;
    }
    fillSimForm(await api("GET", "/sim/config"));
    showPlant(await api("GET", "/sim"));
  } catch (e) { simMsg(e.message, true); }
  connectTelemetry();
  setInterval(pullTelemetry, 1000 / RENDER_HZ);
  pollHealth(); setInterval(pollHealth, 1000);
  setInterval(refreshCameras, 1000 / CAMERA_HZ);
  refreshRecordings(); setInterval(refreshRecordings, 5000);
  refreshRecordingBudget(); setInterval(refreshRecordingBudget, 2000);
}

init();
