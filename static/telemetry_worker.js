// aar-dock: the telemetry WebSocket, off the page's main thread.
//
// A 3-D view drawn in software (no GPU) keeps the page's main thread busy; the 30 Hz telemetry
// messages then queued up behind it and the numbers lagged seconds (tens of seconds) behind.
// Here the messages are taken as they come, on the worker's own thread, and only the newest
// state is kept; the page asks for it when it redraws (one request in flight at a time), so
// nothing can queue up on the page's side.
"use strict";

const CHART_WINDOW_S = 10;
let url = null;
let conn = "connecting";
let latest = null;
let seq = 0; // messages taken (the page redraws only when it changed)
let lastMiss = null; // {miss, captured, run}: the last drogue-plane crossing (set on one tick)
let lastOutcome = null; // {outcome, run}: the last run's outcome class (set on its last tick)
let lastContact = null; // {peak, run}: the multi-body hose's peak tension (N) of the last latched contact
let chartRun = null;
const series = []; // {t, y, z, lat} of the current run only

function connect() {
  const ws = new WebSocket(url);
  ws.onopen = () => { conn = "live"; };
  ws.onclose = () => { conn = "closed"; setTimeout(connect, 1000); };
  ws.onmessage = (ev) => {
    const rec = JSON.parse(ev.data);
    latest = rec;
    seq += 1;
    if (rec.source !== "sim") return;
    if (rec.miss_m !== null && rec.miss_m !== undefined) lastMiss = { miss: rec.miss_m, captured: rec.captured, run: rec.run };
    if (rec.run_outcome) lastOutcome = { outcome: rec.run_outcome, run: rec.run };
    const peak = rec.hose ? rec.hose.contact_peak_tension_n : null;
    if (peak !== null && peak !== undefined) lastContact = { peak, run: rec.run };
    if (rec.run !== chartRun || (series.length && rec.t_s < series[series.length - 1].t)) {
      series.length = 0; // a new run: its own line, never joined to the last run's
      chartRun = rec.run;
    }
    if (rec.rel_position_m) {
      const r = rec.rel_position_m;
      series.push({ t: rec.t_s, y: r[1], z: r[2], lat: Math.hypot(r[1], r[2]) });
      while (series.length && series[0].t < rec.t_s - CHART_WINDOW_S) series.shift();
    }
  };
}

self.onmessage = (ev) => {
  const msg = ev.data;
  if (msg.type === "connect" && url === null) {
    url = msg.url;
    connect();
  } else if (msg.type === "snapshot") {
    self.postMessage({ conn, seq, latest, lastMiss, lastOutcome, lastContact, series: msg.since === seq ? null : series });
  }
};
