/* drivesense live monitor dashboard: plain JavaScript, no framework, no external resources.
 *
 * One WebSocket (/ws) brings a "hello" (machines and logged events), then "frame" messages (5 per s:
 * force of the last 2 s and the status of every machine) and "event" messages.  A "resync" message
 * means events were lost to this (slow) client: they are re-read from /api/events?since=<last seq>.
 * The spectra are polled from /api/machines/{id}/spectrum every second.  While the WebSocket is down (a
 * proxy that does not pass WebSockets, a server restarting) the page polls /api/machines and /api/events
 * every 2 s instead, and says so: it never shows "No events yet" while the service has logged some.
 */
(function () {
  "use strict";

  var RED_KINDS = { breakage: true, collision: true };
  var AMBER_KINDS = { chipping: true, chatter: true, overload: true, missing_tool: true };
  var TOKEN_KEY = "drivesense-token";
  var WINDOW_S = 2.0;

  var machines = {};      // id -> {status, el, force, rate, lastSamples, lastTime}
  var events = {};        // id -> record
  var lastSeq = 0;
  var ws = null;
  var retryMs = 1000;
  var lastFrameAt = 0;
  var connected = false;

  function $(id) { return document.getElementById(id); }
  function el(tag, cls, text) {
    var e = document.createElement(tag);
    if (cls) e.className = cls;
    if (text !== undefined && text !== null) e.textContent = text;
    return e;
  }
  function fmt(v, digits) {
    return (v === null || v === undefined || !isFinite(v)) ? "\u2014" : Number(v).toFixed(digits);
  }
  function fmtBig(v) {
    if (v === null || v === undefined || !isFinite(v)) return "\u2014";
    if (Math.abs(v) >= 1e6) return (v / 1e6).toFixed(2) + "M";
    if (Math.abs(v) >= 1e4) return (v / 1e3).toFixed(1) + "k";
    return String(Math.round(v));
  }
  function clock(epochS) {
    var d = new Date(epochS * 1000);
    function p(n) { return (n < 10 ? "0" : "") + n; }
    return p(d.getHours()) + ":" + p(d.getMinutes()) + ":" + p(d.getSeconds()) + "." + Math.floor(d.getMilliseconds() / 100);
  }

  /* ------------------------------------------------------------------ connection state */
  function setConn(kind, text) {
    var c = $("conn");
    c.className = "pill pill-" + kind;
    c.lastChild.textContent = text;
  }

  /* While the WebSocket is down: machine states and events by plain HTTP (no force traces). */
  function pollFallback() {
    if (connected) return;
    fetch("/api/machines").then(function (r) { return r.ok ? r.json() : null; })
      .then(function (list) {
        if (!list || connected) return;
        list.forEach(function (st) { ensureMachine(st.machine).status = st; renderStatus(st.machine); });
        setConn("wait", "live stream unavailable \u2014 polling every 2 s");
      })
      .catch(function () { /* the server is down: the WebSocket retry says so */ });
    resync();
  }

  function connect() {
    var url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws";
    setConn("wait", connected ? "reconnecting" : "connecting");
    ws = new WebSocket(url);
    ws.onopen = function () { retryMs = 1000; };
    ws.onmessage = function (msg) {
      var m;
      try { m = JSON.parse(msg.data); } catch (e) { return; }
      if (m.type === "hello") onHello(m);
      else if (m.type === "frame") onFrame(m);
      else if (m.type === "event") addEvent(m.event, true);
      else if (m.type === "resync") resync();
    };
    ws.onclose = function () {
      connected = false;
      setConn("bad", "disconnected \u2014 retrying");
      setTimeout(connect, retryMs);
      retryMs = Math.min(retryMs * 2, 8000);
    };
  }

  function onHello(m) {
    connected = true;
    setConn("ok", "live");
    if (m.service && m.service.name) { $("service-name").textContent = m.service.name; document.title = m.service.name; }
    (m.machines || []).forEach(function (st) { ensureMachine(st.machine).status = st; renderStatus(st.machine); });
    (m.events || []).forEach(function (r) { addEvent(r, false); });
    renderEvents();
  }

  function onFrame(f) {
    lastFrameAt = Date.now();
    if (!connected) { connected = true; }
    setConn("ok", "live");
    Object.keys(f.machines || {}).forEach(function (id) {
      var mm = ensureMachine(id), data = f.machines[id];
      if (data.status) {
        var st = data.status;
        if (mm.lastTime && f.time > mm.lastTime) {
          var r = (st.samples - mm.lastSamples) / (f.time - mm.lastTime);
          mm.rate = mm.rate === null ? r : 0.7 * mm.rate + 0.3 * r;
        }
        mm.lastSamples = st.samples; mm.lastTime = f.time;
        mm.status = st;
        renderStatus(id);
      }
      if (data.force) { mm.force = data.force; drawForces(id); }
    });
  }

  function resync() {
    fetch("/api/events?since=" + lastSeq + "&limit=10000").then(function (r) { return r.json(); })
      .then(function (list) { list.forEach(function (r) { addEvent(r, false); }); renderEvents(); })
      .catch(function () { /* the next resync or reconnect catches up */ });
  }

  /* ------------------------------------------------------------------ machine cards */
  function ensureMachine(id) {
    if (machines[id]) return machines[id];
    var mm = { id: id, status: null, force: null, rate: null, lastSamples: 0, lastTime: 0, axes: [], el: {} };
    machines[id] = mm;
    var card = el("article", "card machine");
    card.id = "machine-" + id;
    var head = el("div", "card-head");
    head.appendChild(el("h2", null, id));
    mm.el.state = head.appendChild(el("span", "badge", "\u2026"));
    mm.el.source = head.appendChild(el("span", "source", ""));
    head.appendChild(el("span", "spacer"));
    mm.el.fs = head.appendChild(el("span", "source", ""));
    card.appendChild(head);
    mm.el.error = card.appendChild(el("div", "error-line", ""));
    var kpis = el("div", "kpis");
    [["rate", "Samples/s"], ["lag", "Lag"], ["queue", "Queue"], ["rejected", "Rejected"], ["gaps", "Gaps"],
     ["restarts", "Restarts"]].forEach(function (k) {
      var box = el("div", "kpi");
      box.appendChild(el("label", null, k[1]));
      mm.el[k[0]] = box.appendChild(el("b", null, "\u2014"));
      mm.el[k[0] + "Box"] = box;
      kpis.appendChild(box);
    });
    card.appendChild(kpis);
    var grid = el("div", "body-grid");
    mm.el.plots = grid.appendChild(el("div", "plots"));
    var side = grid.appendChild(el("div", "side"));
    var spec = side.appendChild(el("div", "plot"));
    var st = spec.appendChild(el("div", "plot-title"));
    mm.el.specTitle = st.appendChild(el("b", null, "Force spectrum"));
    mm.el.specPeak = st.appendChild(el("span", null, ""));
    mm.el.spectrum = spec.appendChild(el("canvas", "spectrum-canvas"));
    mm.el.spectrum.id = "spectrum-" + id;
    var stats = side.appendChild(el("div", "stats"));
    var table = stats.appendChild(el("table"));
    table.innerHTML = "<thead><tr><th>Detector</th><th>Axis</th><th class=\"num\">Statistic</th>" +
      "<th class=\"num\">Threshold</th><th>Level</th></tr></thead>";
    mm.el.stats = table.appendChild(el("tbody"));
    mm.el.stats.id = "stats-" + id;
    card.appendChild(grid);
    $("machines").appendChild(card);
    return mm;
  }

  function ensureAxes(mm, axes) {
    if (mm.axes.join() === axes.join()) return;
    mm.axes = axes.slice();
    mm.el.plots.textContent = "";
    mm.el.force = {};
    mm.el.limitLabel = {};
    mm.el.peak = {};
    axes.forEach(function (a) {
      var box = mm.el.plots.appendChild(el("div", "plot force-plot"));
      var t = box.appendChild(el("div", "plot-title"));
      t.appendChild(el("b", null, "Force " + a.toUpperCase() + " [N] \u2014 last " + WINDOW_S + " s"));
      var right = t.appendChild(el("span"));
      mm.el.peak[a] = right.appendChild(el("span", "peak", ""));
      mm.el.limitLabel[a] = right.appendChild(el("span", null, ""));
      right.appendChild(document.createTextNode(" "));
      var edit = right.appendChild(el("button", "linkish", "set limit"));
      edit.type = "button";
      edit.onclick = function () { editLimit(mm.id, a); };
      var c = box.appendChild(el("div", "canvas-box")).appendChild(el("canvas", "force-canvas"));
      c.id = "force-" + mm.id + "-" + a;
      c.setAttribute("data-updates", "0");
      mm.el.force[a] = c;
    });
    mm.el.specTitle.textContent = "Force spectrum " + axes[0].toUpperCase() + " (last 0.5 s)";
  }

  function renderStatus(id) {
    var mm = machines[id], st = mm.status;
    if (!st) return;
    ensureAxes(mm, st.axes || ["x"]);
    renderBadge(id);
    var src = st.source || {};
    var bits = [src.kind || "source"];
    if (src.name) bits.push(src.name);
    if (src.cuts !== undefined) bits.push(src.cuts + (src.cuts === 1 ? " cut" : " cuts") + " played");
    if (src.speed !== undefined) bits.push(src.speed === 0 ? "as fast as possible" : src.speed + "\u00d7 real time");
    mm.el.source.textContent = bits.join(" \u00b7 ");
    mm.el.fs.textContent = st.fs ? (st.fs / 1000).toFixed(st.fs % 1000 ? 2 : 0) + " kHz \u00b7 " +
      fmtBig(st.samples) + " samples" : "waiting for data";
    mm.el.error.textContent = st.source_error ? "source: " + st.source_error :
      (st.last_error ? "last refused: " + st.last_error : "");
    mm.el.rate.textContent = mm.rate === null ? "\u2014" : fmtBig(mm.rate);
    mm.el.lag.innerHTML = fmt(st.lag_s * 1000, 1) + "<small>ms</small>";
    mm.el.lagBox.className = "kpi" + (st.lag_s > 1 ? " bad" : st.lag_s > 0.25 ? " warn" : "");
    mm.el.queue.innerHTML = st.queue + "<small>/ " + st.queue_max + "</small>";
    mm.el.queueBox.className = "kpi" + (st.queue > 0.75 * st.queue_max ? " bad" : st.queue > 0.25 * st.queue_max ? " warn" : "");
    mm.el.rejected.textContent = st.rejected;
    mm.el.rejectedBox.className = "kpi" + (st.rejected > 0 ? " warn" : "");
    mm.el.gaps.textContent = st.gaps;
    mm.el.gapsBox.className = "kpi" + (st.gaps > 0 ? " warn" : "");
    mm.el.restarts.textContent = st.restarts;
    mm.el.restartsBox.className = "kpi" + (st.restarts > 0 ? " warn" : "");
    (st.axes || []).forEach(function (a) {
      var lim = st.limits ? st.limits[a] : null;
      if (mm.el.limitLabel[a]) mm.el.limitLabel[a].textContent = lim ? "limit \u00b1" + fmt(lim, 0) + " N" : "no limit";
    });
    renderStats(mm, st.statistics || []);
  }

  function renderStats(mm, stats) {
    var body = mm.el.stats;
    body.textContent = "";
    if (!stats.length) {
      var r = body.appendChild(el("tr"));
      var td = r.appendChild(el("td", "stats-empty", "no statistics yet"));
      td.colSpan = 5;
      return;
    }
    stats.forEach(function (s) {
      var ratio = (s.statistic !== null && s.threshold) ? Math.abs(s.statistic / s.threshold) : null;
      var tr = body.appendChild(el("tr", ratio !== null && ratio >= 1 ? "over" : ""));
      tr.appendChild(el("td", null, s.detector));
      tr.appendChild(el("td", null, s.axis));
      tr.appendChild(el("td", "num", fmt(s.statistic, 3)));
      tr.appendChild(el("td", "num", fmt(s.threshold, 3)));
      var bar = tr.appendChild(el("td")).appendChild(el("div", "bar")).appendChild(el("span"));
      bar.style.width = (ratio === null ? 0 : Math.min(100, 100 * ratio)) + "%";
    });
  }

  /* ------------------------------------------------------------------ plots */
  function prepare(canvas) {
    var dpr = window.devicePixelRatio || 1;
    var w = canvas.clientWidth || 600, h = canvas.clientHeight || 200;
    if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
      canvas.width = Math.round(w * dpr);
      canvas.height = Math.round(h * dpr);
    }
    var ctx = canvas.getContext("2d");
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    ctx.font = "11px system-ui, sans-serif";
    return { ctx: ctx, w: w, h: h };
  }

  function niceStep(span, n) {
    var raw = span / n, p = Math.pow(10, Math.floor(Math.log10(raw))), m = raw / p;
    return (m < 1.5 ? 1 : m < 3.5 ? 2 : m < 7.5 ? 5 : 10) * p;
  }

  function drawForces(id) {
    var mm = machines[id];
    mm.axes.forEach(function (a) { drawForce(mm, a); });
  }

  function drawForce(mm, axis) {
    var canvas = mm.el.force && mm.el.force[axis];
    if (!canvas) return;
    var g = prepare(canvas), ctx = g.ctx;
    var L = 52, R = 10, T = 10, B = 22, pw = g.w - L - R, ph = g.h - T - B;
    var t = (mm.force && mm.force.t) || [], f = (mm.force && mm.force["force_" + axis]) || [];
    var tEnd = t.length ? t[t.length - 1] : 0;
    var lo = 0, hi = 0;
    for (var i = 0; i < f.length; i++) {
      if (f[i] === null) continue;
      if (f[i] < lo) lo = f[i];
      if (f[i] > hi) hi = f[i];
    }
    var limit = mm.status && mm.status.limits ? mm.status.limits[axis] : null;
    var pad = Math.max(0.12 * (hi - lo), 2);
    var ymin = lo < 0 ? lo - pad : 0, ymax = hi + pad;
    if (ymax - ymin < 20) ymax = ymin + 20;
    var showHi = limit && limit <= 2.5 * Math.max(hi, 1), showLo = limit && lo < 0 && -limit >= 2.5 * Math.min(lo, -1);
    if (showHi) ymax = Math.max(ymax, limit * 1.08);
    if (showLo) ymin = Math.min(ymin, -limit * 1.08);
    if (mm.el.peak && mm.el.peak[axis]) mm.el.peak[axis].textContent = t.length ? "peak " + fmt(Math.max(hi, -lo), 1) + " N" : "";
    function X(tt) { return L + pw * (1 - (tEnd - tt) / WINDOW_S); }
    function Y(v) { return T + ph * (ymax - v) / (ymax - ymin); }
    // grid and ticks
    ctx.strokeStyle = "#1f2b38"; ctx.fillStyle = "#8b9bab"; ctx.lineWidth = 1;
    var step = niceStep(ymax - ymin, 5);
    ctx.textAlign = "right"; ctx.textBaseline = "middle";
    for (var v = Math.ceil(ymin / step) * step; v <= ymax + 1e-9; v += step) {
      ctx.beginPath(); ctx.moveTo(L, Y(v) + 0.5); ctx.lineTo(L + pw, Y(v) + 0.5); ctx.stroke();
      ctx.fillText(Math.abs(v) < 1e-9 ? "0" : v.toFixed(step < 1 ? 1 : 0), L - 6, Y(v));
    }
    ctx.textAlign = "center"; ctx.textBaseline = "top";
    for (var s = 0; s <= WINDOW_S + 1e-9; s += 0.5) {
      var x = L + pw * (1 - s / WINDOW_S);
      ctx.beginPath(); ctx.moveTo(x + 0.5, T); ctx.lineTo(x + 0.5, T + ph); ctx.stroke();
      ctx.fillText(s === 0 ? "now" : "\u2212" + s.toFixed(1) + " s", x, T + ph + 5);
    }
    ctx.strokeStyle = "#2d3d4f"; ctx.strokeRect(L + 0.5, T + 0.5, pw, ph);
    // events in the window
    Object.keys(events).forEach(function (k) {
      var e = events[k];
      if (e.machine !== mm.id || e.axis !== axis || e.time_s === null || !t.length) return;
      if (e.time_s < tEnd - WINDOW_S || e.time_s > tEnd) return;
      var ex = X(e.time_s);
      ctx.strokeStyle = RED_KINDS[e.kind] ? "#f85149" : "#e3b341"; ctx.lineWidth = 2;
      ctx.beginPath(); ctx.moveTo(ex, T); ctx.lineTo(ex, T + ph); ctx.stroke();
      ctx.fillStyle = ctx.strokeStyle; ctx.textAlign = "left"; ctx.textBaseline = "top";
      ctx.font = "bold 11px system-ui, sans-serif";
      ctx.fillText(e.kind.toUpperCase(), Math.min(ex + 4, L + pw - 70), T + 4);
      ctx.font = "11px system-ui, sans-serif";
    });
    // limit
    ctx.save();
    ctx.beginPath(); ctx.rect(L, T, pw, ph); ctx.clip();
    ctx.strokeStyle = "#f85149"; ctx.lineWidth = 1.5; ctx.setLineDash([7, 5]);
    [showHi ? limit : null, showLo ? -limit : null].forEach(function (lv) {
      if (lv === null) return;
      ctx.beginPath(); ctx.moveTo(L, Y(lv)); ctx.lineTo(L + pw, Y(lv)); ctx.stroke();
    });
    ctx.setLineDash([]);
    // trace
    ctx.strokeStyle = "#4cc3ff"; ctx.lineWidth = 1.3; ctx.lineJoin = "round";
    ctx.beginPath();
    var started = false;
    for (var j = 0; j < t.length; j++) {
      if (f[j] === null || f[j] === undefined) { started = false; continue; }
      var px = X(t[j]), py = Y(f[j]);
      if (!started) { ctx.moveTo(px, py); started = true; } else ctx.lineTo(px, py);
    }
    ctx.stroke();
    ctx.restore();
    if (limit && !showHi && !showLo) {
      ctx.fillStyle = "#f85149"; ctx.textAlign = "right"; ctx.textBaseline = "top";
      ctx.fillText("limit \u00b1" + Math.round(limit) + " N (off scale) \u2191", L + pw - 6, T + 4);
    }
    if (!t.length) {
      ctx.fillStyle = "#8b9bab"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
      ctx.fillText("waiting for data", L + pw / 2, T + ph / 2);
    }
    canvas.setAttribute("data-updates", String(Number(canvas.getAttribute("data-updates") || 0) + 1));
  }

  function drawSpectrum(mm, spec) {
    var canvas = mm.el.spectrum, g = prepare(canvas), ctx = g.ctx;
    var L = 44, R = 10, T = 8, B = 20, pw = g.w - L - R, ph = g.h - T - B;
    var fr = spec.f || [], amp = spec.amplitude || [];
    var fmax = 1000;
    if (fr.length && fr[fr.length - 1] < fmax) fmax = fr[fr.length - 1];
    var amax = 0, fpk = null;
    for (var i = 1; i < fr.length && fr[i] <= fmax; i++) if (amp[i] > amax) { amax = amp[i]; fpk = fr[i]; }
    amax = Math.max(amax * 1.15, 1e-3);
    function X(f) { return L + pw * f / fmax; }
    function Y(a) { return T + ph * (1 - a / amax); }
    ctx.strokeStyle = "#1f2b38"; ctx.fillStyle = "#8b9bab"; ctx.lineWidth = 1;
    ctx.textAlign = "center"; ctx.textBaseline = "top";
    var fs = niceStep(fmax, 5);
    for (var f = 0; f <= fmax + 1e-9; f += fs) {
      ctx.beginPath(); ctx.moveTo(X(f) + 0.5, T); ctx.lineTo(X(f) + 0.5, T + ph); ctx.stroke();
      ctx.textAlign = f === 0 ? "left" : (f + fs > fmax + 1e-9 ? "right" : "center");
      ctx.fillText(f + (f + fs > fmax + 1e-9 ? " Hz" : ""), X(f), T + ph + 4);
    }
    ctx.textAlign = "right"; ctx.textBaseline = "middle";
    var as = niceStep(amax, 3);
    for (var a = 0; a <= amax; a += as) {
      ctx.beginPath(); ctx.moveTo(L, Y(a) + 0.5); ctx.lineTo(L + pw, Y(a) + 0.5); ctx.stroke();
      ctx.fillText(a.toFixed(as < 1 ? 1 : 0), L - 5, Y(a));
    }
    ctx.strokeStyle = "#2d3d4f"; ctx.strokeRect(L + 0.5, T + 0.5, pw, ph);
    if (!fr.length) {
      ctx.textAlign = "center"; ctx.textBaseline = "middle"; ctx.fillText("waiting for data", L + pw / 2, T + ph / 2);
      mm.el.specPeak.textContent = "";
      return;
    }
    ctx.beginPath(); ctx.moveTo(X(0), Y(0));
    for (var j = 0; j < fr.length && fr[j] <= fmax; j++) ctx.lineTo(X(fr[j]), Y(amp[j] || 0));
    ctx.lineTo(X(Math.min(fmax, fr[j - 1])), Y(0)); ctx.closePath();
    ctx.fillStyle = "rgba(76, 195, 255, 0.22)"; ctx.fill();
    ctx.strokeStyle = "#4cc3ff"; ctx.lineWidth = 1.2; ctx.stroke();
    mm.el.specPeak.textContent = fpk === null ? "" : "peak " + fmt(amax / 1.15, 1) + " N at " + Math.round(fpk) + " Hz";
  }

  function pollSpectra() {
    Object.keys(machines).forEach(function (id) {
      var mm = machines[id];
      if (!mm.axes.length || mm.spectrumBusy) return;
      mm.spectrumBusy = true;
      fetch("/api/machines/" + encodeURIComponent(id) + "/spectrum?axis=" + encodeURIComponent(mm.axes[0]))
        .then(function (r) { return r.ok ? r.json() : null; })
        .then(function (s) { if (s) drawSpectrum(mm, s); })
        .catch(function () {})
        .then(function () { mm.spectrumBusy = false; });
    });
  }

  /* ------------------------------------------------------------------ events */
  function addEvent(r, render) {
    if (!r || !r.id) return;
    var old = events[r.id];
    events[r.id] = old ? Object.assign({}, old, r, { acknowledged: old.acknowledged || r.acknowledged }) : r;
    if (r.seq && r.seq > lastSeq) lastSeq = r.seq;
    if (render) renderEvents();
  }

  /* The machine's badge: its source state, or ALARM (red) while it has an unacknowledged alarm (mm.alarmed,
   * set by renderEvents: the frames, 5 per s, do not walk the event list). */
  function renderBadge(id) {
    var mm = machines[id], st = mm.status;
    if (!st) return;
    var alarmed = !!mm.alarmed;
    mm.el.state.textContent = alarmed ? "alarm" : st.state;
    mm.el.state.className = "badge state-" + (alarmed ? "alarm" : st.state);
    mm.el.state.title = alarmed ? "unacknowledged alarm; source " + st.state : "source " + st.state;
  }

  function severity(kind) { return RED_KINDS[kind] ? "sev-red" : AMBER_KINDS[kind] ? "sev-amber" : ""; }

  function renderEvents() {
    var list = Object.keys(events).map(function (k) { return events[k]; });
    list.sort(function (a, b) { return (b.seq || 0) - (a.seq || 0); });
    var body = $("events");
    var rows = {};
    Array.prototype.forEach.call(body.children, function (tr) { rows[tr.getAttribute("data-id")] = tr; });
    list.forEach(function (e, i) {
      var tr = rows[e.id];
      var stamp = e.kind + "|" + e.acknowledged;
      if (!tr || tr.getAttribute("data-stamp") !== stamp) {
        var fresh = eventRow(e);
        fresh.setAttribute("data-stamp", stamp);
        if (tr) body.replaceChild(fresh, tr);
        tr = fresh;
      }
      if (body.children[i] !== tr) body.insertBefore(tr, body.children[i] || null);
    });
    $("no-events").hidden = list.length > 0;
    var open = list.filter(function (e) { return RED_KINDS[e.kind] && !e.acknowledged; });
    $("event-count").textContent = list.length + " logged" + (open.length ? " \u00b7 " + open.length + " unacknowledged alarm" +
      (open.length > 1 ? "s" : "") : "");
    $("summary").textContent = Object.keys(machines).length + " machine" + (Object.keys(machines).length === 1 ? "" : "s") +
      " \u00b7 " + (open.length ? open.length + " open alarm" + (open.length > 1 ? "s" : "") : "no open alarm");
    Object.keys(machines).forEach(function (id) {
      var card = $("machine-" + id);
      machines[id].alarmed = open.some(function (e) { return e.machine === id; });
      if (card) card.classList.toggle("alarmed", machines[id].alarmed);
      renderBadge(id);
    });
    var banner = $("alarm");
    if (open.length) {
      var a = open[0];
      $("alarm-kind").textContent = a.kind;
      $("alarm-detail").textContent = "machine " + a.machine + ", axis " + a.axis + " \u2014 detected " +
        clock(a.detected) + " (sample time " + fmt(a.time_s, 3) + " s), confidence " + fmt(100 * a.confidence, 0) + " %" +
        (ncContext(a) ? ", " + ncContext(a) : "");
      $("alarm-ack").onclick = function () { acknowledge(a.id); };
      banner.hidden = false;
    } else {
      banner.hidden = true;
    }
  }

  /* The NC's context at the event (tool and block), as the controller reported it; "" without one. */
  function ncContext(e) {
    var ev = e.evidence || {}, bits = [];
    if (ev.tool_number !== undefined && ev.tool_number !== null) bits.push("T" + ev.tool_number);
    if (ev.block_number !== undefined && ev.block_number !== null) bits.push("N" + ev.block_number);
    return bits.join(" \u00b7 ");
  }

  function eventRow(e) {
    var tr = el("tr", severity(e.kind) + (e.acknowledged ? " acked" : ""));
    tr.setAttribute("data-kind", e.kind);
    tr.setAttribute("data-id", e.id);
    tr.setAttribute("data-seq", e.seq || 0);
    tr.appendChild(el("td", "num", e.detected ? clock(e.detected) : "\u2014"));
    tr.appendChild(el("td", null, e.machine));
    tr.appendChild(el("td", "kind", e.kind));
    tr.appendChild(el("td", null, e.axis));
    tr.appendChild(el("td", "num", fmt(e.time_s, 3)));
    tr.appendChild(el("td", "num", e.confidence === null ? "\u2014" : fmt(100 * e.confidence, 0) + " %"));
    tr.appendChild(el("td", "muted", e.detector));
    tr.appendChild(el("td", "nc", ncContext(e) || "\u2014"));
    var act = tr.appendChild(el("td", "act"));
    if (e.acknowledged) {
      act.appendChild(el("span", "acked-mark", "\u2713 acknowledged"));
    } else {
      var b = act.appendChild(el("button", "btn" + (RED_KINDS[e.kind] ? " btn-danger" : ""), "Acknowledge"));
      b.type = "button";
      b.onclick = function () { acknowledge(e.id); };
    }
    return tr;
  }

  /* ------------------------------------------------------------------ writes (need the token) */
  function token() {
    var t = sessionStorage.getItem(TOKEN_KEY);
    if (!t) {
      t = window.prompt("Token for changes (the config's [service] token):", "");
      if (t) sessionStorage.setItem(TOKEN_KEY, t.trim());
    }
    return t ? t.trim() : null;
  }

  function write(method, url, body) {
    var t = token();
    if (!t) return Promise.resolve(null);
    return fetch(url, { method: method, headers: { "Authorization": "Bearer " + t, "Content-Type": "application/json" },
                        body: JSON.stringify(body || {}) })
      .then(function (r) {
        return r.json().then(function (j) {
          if (r.status === 403) sessionStorage.removeItem(TOKEN_KEY);
          if (!r.ok) { window.alert(j.error || ("HTTP " + r.status)); return null; }
          return j;
        });
      })
      .catch(function (err) { window.alert("request failed: " + err); return null; });
  }

  function acknowledge(id) {
    write("POST", "/api/events/" + id.split("/").map(encodeURIComponent).join("/") + "/ack", { by: "dashboard" })
      .then(function (j) {
        if (j && events[id]) { events[id].acknowledged = true; renderEvents(); }
      });
  }

  function editLimit(id, axis) {
    var cur = machines[id].status && machines[id].status.limits ? machines[id].status.limits[axis] : "";
    var v = window.prompt("Force limit of machine " + id + " axis " + axis + " [N]:", cur || "");
    if (v === null || v === "") return;
    write("PUT", "/api/machines/" + encodeURIComponent(id) + "/limits", { axis: axis, force_limit_n: Number(v) })
      .then(function (j) { if (j && machines[id].status) { machines[id].status.limits = j.limits; renderStatus(id); } });
  }

  /* ------------------------------------------------------------------ timers */
  function tick() {
    $("clock").textContent = clock(Date.now() / 1000).slice(0, 8);
    if (connected && lastFrameAt && Date.now() - lastFrameAt > 3000) setConn("wait", "no data for " +
      Math.round((Date.now() - lastFrameAt) / 1000) + " s");
  }

  connect();
  setInterval(pollSpectra, 1000);
  setInterval(pollFallback, 2000);
  setInterval(tick, 500);
  tick();
})();
