// Frame source panel: active source, its rate, drops and skew, the stream guidance numbers;
// switch the source (token-protected) and record with raw frames. Plain DOM, no framework.
(function () {
  "use strict";
  const API = "/api/v1";
  const el = (id) => document.getElementById(id);
  const fmt = (v, d) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(d));

  function headers(json) {
    const h = json ? { "Content-Type": "application/json" } : {};
    const tok = el("token") ? el("token").value.trim() : "";
    if (tok) h.Authorization = "Bearer " + tok;
    return h;
  }

  function msg(text, err) {
    const m = el("src-msg");
    m.textContent = text;
    m.className = "msg" + (err ? " err" : "");
  }

  async function detail(r) {
    try { const b = await r.json(); return typeof b.detail === "string" ? b.detail : JSON.stringify(b.detail); }
    catch (e) { return r.statusText; }
  }

  async function poll() {
    try {
      const r = await fetch(API + "/stream");
      if (r.ok) {
        const s = await r.json();
        el("src-spec").textContent = s.source;
        el("src-state").textContent = s.state;
        el("src-fps").textContent = fmt(s.fps, 1);
        el("src-pairs").textContent = s.pairs;
        el("src-drops").textContent = s.dropped_skew + " / " + s.dropped_backpressure + " / " + s.rejected;
        el("src-skew").textContent = fmt(s.last_skew_ms, 1) + " (max " + fmt(s.max_skew_ms, 1) + ")";
        el("src-error").textContent = s.health_reason || s.last_error || "";
      }
      const st = await fetch(API + "/state");
      if (st.ok) {
        const rec = await st.json();
        const g = rec.guidance || {};
        el("g-closure").textContent = fmt(g.closure_speed_mps, 2);
        el("g-ttc").textContent = fmt(g.time_to_contact_s, 2);
        el("g-miss").textContent = fmt(g.predicted_miss_m, 3);
        el("g-mode").textContent = rec.stream ? rec.stream.mode : "–";
      }
    } catch (e) { /* the service restarts: keep polling */ }
  }

  async function switchSource(ev) {
    ev.preventDefault();
    const body = { source: el("src-input").value.trim() || "sim" };
    if (el("src-fast").checked) body.realtime = false;
    if (el("src-loop").checked) body.loop = true;
    const r = await fetch(API + "/stream/source", { method: "PUT", headers: headers(true), body: JSON.stringify(body) });
    if (r.ok) { msg("source: " + (await r.json()).source); poll(); }
    else msg(r.status + ": " + (await detail(r)), true);
  }

  async function recordFrames() {
    const r = await fetch(API + "/recording/start?frames=true", { method: "POST", headers: headers(false) });
    if (r.ok) msg("recording " + (await r.json()).id + " with frames (stop it under Recordings)");
    else msg(r.status + ": " + (await detail(r)), true);
  }

  document.addEventListener("DOMContentLoaded", () => {
    if (!el("source-panel")) return;
    el("src-form").addEventListener("submit", switchSource);
    el("src-record").addEventListener("click", recordFrames);
    poll();
    setInterval(poll, 1000);
  });
})();
