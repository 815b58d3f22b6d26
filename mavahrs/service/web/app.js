// mavahrs status page: reads /events (Server-Sent Events) and draws; sends nothing back.
"use strict";
(function () {
  const PX_PER_DEG = 2;  // pitch ladder scale, SVG units per degree
  const SVG = "http://www.w3.org/2000/svg";
  const token = new URLSearchParams(location.search).get("token");
  const query = token ? "?token=" + encodeURIComponent(token) : "";
  const $ = (id) => document.getElementById(id);

  function el(name, attrs, parent, text) {
    const e = document.createElementNS(SVG, name);
    for (const k in attrs) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    parent.appendChild(e);
    return e;
  }

  // static drawing: pitch ladder, roll scale, compass rose
  const ladder = $("ladder");
  ladder.setAttribute("class", "ladder");
  for (let p = -60; p <= 60; p += 5) {
    if (p === 0) continue;
    const y = -p * PX_PER_DEG, w = p % 10 === 0 ? 22 : 10;
    el("line", { x1: -w, x2: w, y1: y, y2: y }, ladder);
    if (p % 10 === 0) {
      el("text", { x: -w - 9, y: y }, ladder, Math.abs(p));
      el("text", { x: w + 9, y: y }, ladder, Math.abs(p));
    }
  }
  const scale = $("roll-scale");
  scale.setAttribute("class", "scale");
  for (const a of [-60, -45, -30, -20, -10, 0, 10, 20, 30, 45, 60]) {
    const len = a % 30 === 0 ? 10 : 6;
    el("line", { x1: 0, x2: 0, y1: -94, y2: -94 + len, transform: "rotate(" + a + ")" }, scale);
  }
  const rose = $("rose");
  for (let d = 0; d < 360; d += 5) {
    const major = d % 30 === 0;
    el("line", { x1: 0, x2: 0, y1: -92, y2: major ? -80 : (d % 10 === 0 ? -85 : -88),
      class: major ? "major" : "", transform: "rotate(" + d + ")" }, rose);
    if (major) {
      const names = { 0: "N", 90: "E", 180: "S", 270: "W" };
      const label = names[d] || String(d / 10);
      el("text", { x: 0, y: -68, transform: "rotate(" + d + ")", class: d === 0 ? "north" : "" }, rose, label);
    }
  }

  const fmt = (v, digits) => (v === null || v === undefined || !isFinite(v)) ? "–" : Number(v).toFixed(digits);
  const signed = (v, digits) => (v === null || v === undefined || !isFinite(v)) ? "–" : (v >= 0 ? "+" : "") + Number(v).toFixed(digits);
  const set = (id, text) => { const e = $(id); if (e.textContent !== text) e.textContent = text; };
  const horizonTransform = (roll, pitch) => "rotate(" + (-roll).toFixed(2) + ") translate(0 " + (pitch * PX_PER_DEG).toFixed(2) + ")";

  function badge(id, cls, text) {
    const e = $(id);
    e.className = "badge " + cls;
    e.textContent = text;
  }

  function onAttitude(msg) {
    const a = msg.attitude;
    const body = document.body;
    body.dataset.attitudeUpdates = String(Number(body.dataset.attitudeUpdates) + 1);
    badge("health", msg.healthy ? "ok" : "bad", msg.healthy ? "link OK" : msg.health);
    set("uptime", formatDuration(a.uptime_s));
    const horizon = $("horizon");
    if (a.q) {
      $("sky-ground").setAttribute("transform", horizonTransform(a.roll_deg, a.pitch_deg));
      $("roll-pointer").setAttribute("transform", "rotate(" + (-a.roll_deg).toFixed(2) + ")");
      $("rose").setAttribute("transform", "rotate(" + (-a.yaw_deg).toFixed(2) + ")");
      horizon.dataset.rollDeg = a.roll_deg.toFixed(3);
      horizon.dataset.pitchDeg = a.pitch_deg.toFixed(3);
      horizon.dataset.timeBootMs = String(a.time_boot_ms);
      $("compass").dataset.yawDeg = a.yaw_deg.toFixed(3);
      set("roll", signed(a.roll_deg, 1));
      set("pitch", signed(a.pitch_deg, 1));
      set("yaw", fmt(a.yaw_deg, 0).padStart(3, "0"));
    }
    const ap = a.autopilot;
    const ghost = $("ap-ghost"), apHeading = $("ap-heading");
    if (ap && a.q) {
      ghost.setAttribute("visibility", "visible");
      apHeading.setAttribute("visibility", "visible");
      // the autopilot's horizon drawn in the same frame as ours: rotated by its roll, shifted by its pitch
      ghost.setAttribute("transform", horizonTransform(ap.roll_deg, ap.pitch_deg));
      apHeading.setAttribute("transform", "rotate(" + (ap.yaw_deg - a.yaw_deg).toFixed(2) + ")");
      set("ap-roll", signed(ap.roll_deg, 1));
      set("ap-pitch", signed(ap.pitch_deg, 1));
      set("ap-yaw", fmt(ap.yaw_deg, 0));
    } else {
      ghost.setAttribute("visibility", "hidden");
      apHeading.setAttribute("visibility", "hidden");
    }
    const d = a.difference;
    set("diff-tilt", d ? fmt(d.tilt_deg, 1) : "–");
    set("diff-heading", d ? signed(d.heading_deg, 1) : "–");
    set("diff-time", d ? "boot " + (d.time_boot_ms / 1000).toFixed(1) + " s" : "–");
  }

  function formatDuration(s) {
    if (s === null || s === undefined) return "–";
    s = Math.floor(s);
    const h = Math.floor(s / 3600), m = Math.floor(s / 60) % 60, sec = s % 60;
    return (h ? h + " h " : "") + (h || m ? m + " min " : "") + sec + " s";
  }

  function bar(id, weight) {
    const e = $(id);
    const w = isFinite(weight) && weight !== null ? Math.max(0, Math.min(1, weight)) : 0;
    e.style.width = (w * 100).toFixed(0) + "%";
    e.className = w < 0.5 ? "low" : "";
  }

  // the strip chart: the last minutes of tilt and heading divergence, the threshold, the warnings
  const SVGNS = "http://www.w3.org/2000/svg";
  function drawStrip(st) {
    const svg = $("strip");
    const n = st && st.t_s ? st.t_s.length : 0;
    svg.dataset.points = String(n);
    if (n < 2) return;
    const t0 = st.t_s[0], t1 = st.t_s[n - 1], span = Math.max(t1 - t0, 1);
    const x = (t) => ((t - t0) / span * 1000).toFixed(1);
    const top = (vals, thr) => {
      let m = 0;
      for (let i = 0; i < n; i++) {
        const v = Math.abs(vals[i]), h = thr[i];
        if (isFinite(v) && v !== null && v > m) m = v;
        if (isFinite(h) && h !== null && h > m) m = h;
      }
      return m > 0 ? m * 1.1 : 1;
    };
    const line = (id, vals, scale) => {
      const pts = [];
      for (let i = 0; i < n; i++) {
        const v = vals[i];
        if (v === null || !isFinite(v)) continue;
        pts.push(x(st.t_s[i]) + "," + (100 - Math.min(Math.abs(v), scale) / scale * 96).toFixed(1));
      }
      $(id).setAttribute("points", pts.join(" "));
    };
    const tMax = top(st.tilt_deg, st.tilt_threshold_deg), hMax = top(st.heading_deg, st.heading_threshold_deg);
    line("strip-tilt", st.tilt_deg, tMax);
    line("strip-tilt-thr", st.tilt_threshold_deg, tMax);
    line("strip-hdg", st.heading_deg, hMax);
    line("strip-hdg-thr", st.heading_threshold_deg.map((v) => (v ? v : null)), hMax);
    set("strip-tilt-scale", fmt(tMax, 1));
    set("strip-hdg-scale", fmt(hMax, 1));
    svg.dataset.tiltMaxDeg = fmt(tMax, 2);
    svg.dataset.headingMaxDeg = fmt(hMax, 2);
    svg.dataset.spanS = span.toFixed(1);
    // warning periods shaded, each WARNING / NOTICE raised a mark
    const g = $("strip-warn");
    while (g.firstChild) g.removeChild(g.firstChild);
    let start = null, raised = 0;
    for (let i = 0; i <= n; i++) {
      const on = i < n && st.warning[i];
      if (on && start === null) start = st.t_s[i];
      if (!on && start !== null) {
        const r = document.createElementNS(SVGNS, "rect");
        r.setAttribute("class", "strip-warn");
        r.setAttribute("x", x(start));
        r.setAttribute("width", Math.max(2, x(st.t_s[i - 1]) - x(start)).toFixed(1));
        r.setAttribute("y", "0");
        r.setAttribute("height", "215");
        g.appendChild(r);
        start = null;
      }
      if (i < n && st.raised[i]) {
        const m = document.createElementNS(SVGNS, "line");
        m.setAttribute("class", "strip-mark");
        m.setAttribute("x1", x(st.t_s[i]));
        m.setAttribute("x2", x(st.t_s[i]));
        m.setAttribute("y1", "0");
        m.setAttribute("y2", "215");
        m.dataset.raised = String(st.raised[i]);
        g.appendChild(m);
        raised += st.raised[i] === 2 ? 1 : 0;
      }
    }
    svg.dataset.warnings = String(raised);
    set("strip-span", "the last " + span.toFixed(0) + " s (boot time " + t0.toFixed(0) + "–" + t1.toFixed(0) + " s)");
  }

  // who is likely wrong, while a warning is on
  function showEvidence(so) {
    const e = $("so-evidence");
    e.dataset.cause = so.warning ? so.cause || "" : "";
    var how = so.warning && so.trigger === "step" ? " (raised by a step against its recent baseline, not the dashed line)" : "";
    e.textContent = so.warning && so.evidence_text ? "likely: " + (so.cause || "unclear") + " — " + so.evidence_text + how : "";
    if (so.judged === false) {
      // our IMU input too slow to judge the autopilot (MonitorSettings.min_imu_rate_hz)
      e.dataset.cause = "not-judged";
      e.textContent = "not judged: our IMU input at " + fmt(so.imu_rate_hz, 0) + " Hz is too slow to follow the vehicle";
    }
  }

  function onStatus(s) {
    const body = document.body;
    body.dataset.statusUpdates = String(Number(body.dataset.statusUpdates) + 1);
    set("master", s.master || "");
    set("in-hz", fmt(s.in_hz, 0));
    set("filter-hz", fmt(s.filter_hz, 0));
    set("out-hz", fmt(s.out_hz, 0));
    set("drops", String(s.drops ?? "–"));
    set("link-drops", String(s.link_drops ?? "–"));
    set("crc", String(s.crc_errors ?? "–"));
    set("bad", String(s.bad_data ?? "–"));
    set("gaps", String(s.seq_gaps ?? "–"));
    set("filter", s.filter || "–");
    set("gain", fmt(s.gain, 3));
    bar("accel-bar", s.accel_weight);
    bar("mag-bar", s.mag_weight);
    set("accel-weight", fmt(s.accel_weight, 2) + (s.accel_rejected ? " rejecting" : ""));
    set("mag-weight", fmt(s.mag_weight, 2) + (s.mag_rejected ? " rejecting" : ""));
    set("accel-rej", fmt(s.accel_rejection_pct, 0));
    set("mag-rej", fmt(s.mag_rejection_pct, 0));
    set("bias", s.bias_deg_s ? s.bias_deg_s.map((v) => signed(v, 2)).join("  ") : "–");
    set("gnss", s.gnss_velocity || "–");
    const mm = s.magnetometer;  // the magnetometer's state: the learnt model, or the filter's trust (best / eskf)
    set("mag-state", mm ? (mm.heading_from === "unknown" ? "heading unknown: compass disturbed"
      : mm.state === "disturbed" ? "disturbed: heading from " + (mm.heading_from || "GNSS")
      : mm.state + (mm.model === "off" ? " (model off)" : "")) : "–");
    const decl = mm && typeof mm.declination_correction_deg === "number"
      ? "declination " + signed(mm.declination_correction_deg, 2) + " ± " + fmt(mm.declination_sigma_deg, 2) + "° from the WMM's" : "";
    set("mag-offset", mm && mm.offset_ut ? "offset " + mm.offset_ut.map((v) => signed(v, 1)).join(" ") + " µT · "
      + mm.motor_ut_per_a.map((v) => signed(v, 2)).join(" ") + " µT/A" + (decl ? " · " + decl : "") : decl);
    set("imu", s.imu === null || s.imu === undefined ? "none" : String(s.imu));
    set("imu-reason", s.imu_reason || "");
    set("lat50", fmt(s.latency_p50_us, 0));
    set("lat99", fmt(s.latency_p99_us, 0));
    set("msgs", String(s.messages_in ?? "–"));
    set("atts", String(s.attitudes_out ?? "–"));
    set("profile", s.autopilot_profile || "–");
    set("vehicle", s.vehicle ? "(system " + s.vehicle[0] + ", component " + s.vehicle[1] + ")" : "");
    set("heading-ref", s.heading_reference || "");
    const so = s.second_opinion;
    if (so) {
      set("so-tilt", fmt(so.tilt_deg, 1));
      set("so-heading", signed(so.heading_deg, 1));
      set("so-comparisons", String(so.comparisons));
      set("so-episodes", String(so.episodes));
      set("so-imu-late", String(so.imu_late ?? 0));
      if (so.comparisons === 0) badge("so-alarm", "unknown", "no autopilot attitude");
      else badge("so-alarm", so.warning ? "warn" : "ok", so.warning ? "DIFFERS" : "agrees");
      showEvidence(so);
      drawStrip(so.strip);
    } else {
      badge("so-alarm", "unknown", "off");
    }
    onPilot(s.pilot);
  }

  // the pilot's fields (mavahrs.service.pilot): armed, mode, battery, altitude, speed, GNSS, field, recording, latency
  function onPilot(p) {
    if (!p) return;
    set("armed", p.armed === null ? "–" : p.armed ? "ARMED" : "disarmed");
    set("mode", p.mode || "–");
    const b = p.battery || {};
    set("battery", (b.voltage_v === null ? "–" : fmt(b.voltage_v, 1) + " V") +
        (b.current_a === null ? "" : " · " + fmt(b.current_a, 1) + " A") +
        (b.remaining_pct === null ? "" : " · " + b.remaining_pct + " %"));
    set("altitude", p.altitude_rel_m === null ? "–" : fmt(p.altitude_rel_m, 1) + " m (MSL " + fmt(p.altitude_msl_m, 0) + " m)");
    set("ground-speed", p.ground_speed_m_s === null ? "–" : fmt(p.ground_speed_m_s, 1) + " m/s");
    const g = p.gnss || {};
    set("gnss-fix", g.fix === null ? "–" : g.fix + (g.satellites === null ? "" : ", " + g.satellites + " satellites"));
    set("mag-field", p.mag_field_ut === null ? "–" : fmt(p.mag_field_ut, 1) + " µT" +
        (p.mag_field_expected_ut === null ? "" : " (model " + fmt(p.mag_field_expected_ut, 1) + " µT)"));
    const log = p.log || {};
    set("recording", log.recording ? log.path + (log.bytes === null ? "" : " (" + fmt(log.bytes / 1e6, 1) + " MB)") : "not recording (--log FILE)");
    const l = p.latency || {};
    set("lat-context", l.sample_period_us === null ? "" :
        "p99 " + (l.within_sample_period ? "within" : "beyond") + " the " + fmt(l.sample_period_us, 0) +
        " µs sample period" + (l.output_period_us === null ? "" : "; output every " + fmt(l.output_period_us / 1000, 0) + " ms"));
  }

  $("json-link").setAttribute("href", "status.json" + query);
  $("metrics-link").setAttribute("href", "metrics" + query);
  fetch("register_service").then((r) => r.json()).then((info) => set("version", info.version)).catch(() => {});

  const events = new EventSource("events" + query);
  events.addEventListener("attitude", (e) => onAttitude(JSON.parse(e.data)));
  events.addEventListener("status", (e) => onStatus(JSON.parse(e.data)));
  events.onerror = () => badge("health", "unknown", "no connection to mavahrs");
})();
