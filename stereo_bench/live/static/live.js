// stereo-bench live page: renders the campaign state pushed by the server (Server-Sent Events).
// Shipped with the package; no external scripts. Controls carry the run's token from the page's URL.
"use strict";

const TOKEN = new URLSearchParams(location.search).get("token") || "";
const $ = (id) => document.getElementById(id);
const QUANTITY = {
  baseline_mm: ["B", "mm"], distance_mm: ["Z", "mm"], alpha_deg: ["α", "°"], tilt_deg: ["tilt", "°"],
};
let state = null;

function esc(text) {
  return String(text ?? "").replace(/[&<>"']/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]));
}
function num(value, digits = 3) {
  return value === null || value === undefined || Number.isNaN(value) ? "–" : Number(value).toFixed(digits);
}
function duration(seconds) {
  if (seconds === null || seconds === undefined) return "–";
  const s = Math.max(0, Math.round(seconds));
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), r = s % 60;
  return h ? `${h} h ${String(m).padStart(2, "0")} min` : m ? `${m} min ${String(r).padStart(2, "0")} s` : `${r} s`;
}

// -- controls ------------------------------------------------------------------------------------------------

const PROMPT_ACTIONS = ["continue", "capture_now", "discard_last_view", "set_threshold", "exclude_view", "recalibrate"];

async function act(action, value) {
  const box = $("message");
  try {
    // A prompt's answer names the prompt it was given on: if the run has asked another since, it is refused.
    const params = new URLSearchParams();
    if (value !== undefined) params.set("value", value);
    if (PROMPT_ACTIONS.includes(action) && state && state.prompt && state.prompt.id != null) params.set("prompt", state.prompt.id);
    const query = params.toString() ? `?${params}` : "";
    const response = await fetch(`/api/control/${action}${query}`, {method: "POST", headers: {"X-Token": TOKEN}});
    const body = await response.json();
    box.textContent = body.message;
    box.className = response.ok ? "message" : "message error";
  } catch (error) {
    box.textContent = `${action}: ${error}`;
    box.className = "message error";
  }
  box.hidden = false;
  clearTimeout(act.timer);
  act.timer = setTimeout(() => { box.hidden = true; }, 6000);
}
document.querySelectorAll("button[data-action]").forEach((button) => {
  button.addEventListener("click", () => {
    if (button.dataset.input) return act(button.dataset.action, $(button.dataset.input).value);  // the review's t, x
    act(button.dataset.action === "pause" && state && state.run.paused ? "resume" : button.dataset.action);
  });
});
if (!TOKEN) $("readonly").hidden = false;

// -- previews: fetch the newest JPEG when the last one has loaded (a slow browser just sees fewer frames) -----

const previews = {left: {loading: false, shown: 0, wanted: 0}, right: {loading: false, shown: 0, wanted: 0},
  rectified: {loading: false, shown: 0, wanted: 0}};
// Fetched as a blob and shown once decoded: a pane shows its placeholder until the first frame, never a
// broken-image icon (a frame that fails to load leaves the last one shown).
function loadPreview(side) {
  const p = previews[side];
  if (p.loading || p.wanted <= p.shown) return;
  p.loading = true;
  const version = p.wanted;
  const img = $(`img-${side}`);
  const done = () => { p.loading = false; p.shown = Math.max(p.shown, version); loadPreview(side); };
  fetch(`/preview/${side}.jpg?v=${version}`, {cache: "no-store"})
    .then((response) => (response.ok ? response.blob() : null))
    .then((blob) => {
      if (!blob) { done(); return; }
      const url = URL.createObjectURL(blob);
      const probe = new Image();
      probe.onload = () => {
        const old = img.dataset.url;
        img.onload = () => { if (old) URL.revokeObjectURL(old); img.dataset.version = String(version); img.hidden = false; $(`ph-${side}`).hidden = true; done(); };
        img.dataset.url = url;
        img.src = url;
      };
      probe.onerror = () => { URL.revokeObjectURL(url); done(); };
      probe.src = url;
    })
    .catch(done);
}

function renderPreview(meta) {
  if (!meta) return;
  for (const side of ["left", "right"]) {
    previews[side].wanted = Math.max(previews[side].wanted, meta.version);
    loadPreview(side);
    const n = meta.corners ? meta.corners[side] : 0;
    $(`cap-${side}`).textContent = meta.board ? `· ${n} corners of the ${meta.board === "calibration" ? "calibration board" : "target"}` : "· no board found";
  }
  if (meta.rectified) {
    previews.rectified.wanted = Math.max(previews.rectified.wanted, meta.version);
    loadPreview("rectified");
    $("rectified-label").textContent = `with the calibration of ${meta.rectified}: a corner lies on the same line in both views`;
  }
  const when = meta.source === "live" ? "live" : meta.label;
  $("preview-label").textContent = `${when} · ${meta.in_both} corners in both views`;
  $("skew").textContent = meta.skew_ms === null || meta.skew_ms === undefined ? "left–right skew –" : `left–right skew ${meta.skew_ms.toFixed(1)} ms`;
}

// -- coverage ------------------------------------------------------------------------------------------------

function renderCoverage(coverage) {
  const box = $("coverage");
  if (!coverage) { $("coverage-config").textContent = ""; return; }
  $("coverage-config").textContent = `${coverage.config_id} · ${coverage.views_taken}/${coverage.views_expected} views`;
  box.innerHTML = ["left", "right"].map((side) => {
    const c = coverage[side];
    const bars = c.bars.map((b) => `<div class="bar"><span>${esc(b.name)}</span><span class="track">` +
      `<span class="span" style="left:${(b.low * 100).toFixed(1)}%;width:${(Math.max(0.01, b.high - b.low) * 100).toFixed(1)}%"></span>` +
      `<span class="fill ${b.progress >= 1 ? "done" : ""}" style="width:${(b.progress * 100).toFixed(0)}%"></span></span>` +
      `<span class="pct">${(b.progress * 100).toFixed(0)}%</span></div>`).join("");
    return `<div class="cov"><h3>${side} · ${c.views.length} kept · ${(c.covered * 100).toFixed(0)}% of the image</h3>${bars}` +
      `<canvas class="occupancy" id="occ-${side}" width="320" height="180"></canvas></div>`;
  }).join("");
  for (const side of ["left", "right"]) drawOccupancy($(`occ-${side}`), coverage[side].occupancy);
}

function drawOccupancy(canvas, grid) {
  const ctx = canvas.getContext("2d");
  const rows = grid.length, cols = grid[0].length;
  const w = canvas.width / cols, h = canvas.height / rows;
  const max = Math.max(1, ...grid.flat());
  ctx.fillStyle = "#20242c";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  for (let r = 0; r < rows; r++) {
    for (let c = 0; c < cols; c++) {
      if (!grid[r][c]) continue;
      const t = 0.25 + 0.75 * grid[r][c] / max;
      ctx.fillStyle = `rgba(80, 200, 120, ${t.toFixed(2)})`;
      ctx.fillRect(c * w + 0.5, r * h + 0.5, w - 1, h - 1);
    }
  }
}

function renderCalibration(calibration) {
  if (!calibration) return;
  $("calib-config").textContent = `${calibration.config_id} · RMS ${num(calibration.rms_px, 3)} px`;
  const views = calibration.per_view || [];
  if (views.length) {
    const values = views.flatMap((v) => [v.left_px, v.right_px]).filter((e) => e !== null && e !== undefined);
    const max = Math.max(...values, 0.05);
    const width = 300, height = 76, step = width / views.length, bar = Math.max(1.5, step / 2 - 2);
    const rect = (v, i, which, colour) => {
      const e = v[`${which}_px`];
      if (e === null || e === undefined) return "";
      const h = (e / max) * (height - 24);
      const x = i * step + 1 + (which === "right" ? bar + 1 : 0);
      return `<rect x="${x.toFixed(1)}" y="${(height - 12 - h).toFixed(1)}" width="${bar.toFixed(1)}" height="${h.toFixed(1)}" fill="${colour}"><title>view ${v.index + 1} ${which}: ${e.toFixed(3)} px</title></rect>`;
    };
    const bars = views.map((v, i) => rect(v, i, "left", "#2463eb") + rect(v, i, "right", "#d97706") +
      `<text x="${(i * step + step / 2).toFixed(1)}" y="${height - 1}" text-anchor="middle">${v.index + 1}</text>`).join("");
    $("per-view").innerHTML = `<div class="per-view"><svg viewBox="0 0 ${width} ${height}">${bars}` +
      `<text x="2" y="9">max ${max.toFixed(3)} px</text><text x="${width - 2}" y="9" text-anchor="end">` +
      `<tspan style="fill:#2463eb">■ left</tspan> <tspan style="fill:#d97706">■ right</tspan></text></svg></div>`;
  }
  const rejected = calibration.rejected || [];
  $("rejected").innerHTML = rejected.length ? `<h3>Rejected views</h3><ul class="rejected">` +
    rejected.map((r) => `<li>view ${r.index + 1}: ${esc(r.reason)}</li>`).join("") + "</ul>" : "";
}

// -- rig, plan, results, log -----------------------------------------------------------------------------------

function renderRig(rig) {
  const state = rig.state || "–";
  $("rig-state").textContent = state;
  $("rig-state").className = `pill ${esc(state.split(":")[0])}`;
  const p = rig.position || {};
  const rows = [["baseline B", p.baseline_mm, "mm"], ["toe-in left", p.toe_in_left_deg, "°"], ["toe-in right", p.toe_in_right_deg, "°"],
    ["tilt left", p.tilt_left_deg, "°"], ["tilt right", p.tilt_right_deg, "°"], ["target distance Z", p.target_distance_mm, "mm"]];
  $("rig-position").innerHTML = rows.map(([name, value, unit]) =>
    `<tr><td>${name}</td><td class="num">${value === null || value === undefined ? "–" : `${Number(value).toFixed(2)} ${unit}`}</td></tr>`).join("") +
    `<tr><td>from</td><td>${esc(rig.source || "–")}${(rig.manual || []).length ? "; Z as the operator set it" : ""}</td></tr>`;
  $("alarms").innerHTML = (rig.alarms || []).map((a) => `<div class="alarm">${esc(a)}</div>`).join("");
  const pre = $("transcript");
  const atBottom = pre.scrollTop + pre.clientHeight >= pre.scrollHeight - 4;
  pre.textContent = (rig.transcript || []).join("\n");
  if (atBottom) pre.scrollTop = pre.scrollHeight;
}

// -- the rig in 3-D: cameras, their fields of view to the board, the board (an SVG, from the rig's position) -----

const RIG_VIEW = {yaw: -0.35, pitch: 0.95, halfFovDeg: 30, aspect: 9 / 16, boardMm: [250, 180]};
function renderRig3d(rig, plan) {
  const p = rig.position || {};
  const current = (plan.configs || []).find((c) => c.config_id === plan.current) || {};
  const B = p.baseline_mm ?? current.baseline_mm;
  let Z = p.target_distance_mm ?? current.distance_mm;
  const box = $("rig3d");
  if (B === null || B === undefined) { box.innerHTML = `<p class="muted">The rig appears with its first reading.</p>`; return; }
  Z = Z || 500;
  const rad = Math.PI / 180;
  const cy = Math.cos(RIG_VIEW.yaw), sy = Math.sin(RIG_VIEW.yaw), cp = Math.cos(RIG_VIEW.pitch), sp = Math.sin(RIG_VIEW.pitch);
  // Rig frame (BRIEF): X along the baseline (left camera at -B/2), Y down, Z toward the board. Seen from above
  // and behind: a turn about Y, then a tilt about X; orthographic.
  const view = ([x, y, z]) => { const x1 = cy * x + sy * z, z1 = -sy * x + cy * z; return [x1, cp * y - sp * z1]; };
  const cams = [["left", -B / 2, p.toe_in_left_deg || 0, p.tilt_left_deg || 0], ["right", B / 2, -(p.toe_in_right_deg || 0), p.tilt_right_deg || 0]];
  const h = Math.tan(RIG_VIEW.halfFovDeg * rad), v = h * RIG_VIEW.aspect;
  const shapes = [];
  for (const [name, x, toe, tilt] of cams) {
    const t = toe * rad, k = tilt * rad;
    // Camera axes in the rig frame: toe-in turns the optical axis toward the other camera, tilt > 0 looks down.
    const fwd = [Math.sin(t) * Math.cos(k), Math.sin(k), Math.cos(t) * Math.cos(k)];
    const right = [Math.cos(t), 0, -Math.sin(t)];
    const down = [fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2], fwd[0] * right[1] - fwd[1] * right[0]];
    const at = (a, b) => [0, 1, 2].map((i) => (i === 0 ? x : 0) + Z * (fwd[i] + a * h * right[i] + b * v * down[i]));
    const far = [at(-1, -1), at(1, -1), at(1, 1), at(-1, 1)];
    shapes.push({cls: "frustum", name, apex: [x, 0, 0], far});
  }
  const [bw, bh] = RIG_VIEW.boardMm;
  const board = [[-bw / 2, -bh / 2, Z], [bw / 2, -bh / 2, Z], [bw / 2, bh / 2, Z], [-bw / 2, bh / 2, Z]];
  const points = [board, ...shapes.map((s) => [s.apex, ...s.far])].flat().map(view);
  const xs = points.map((q) => q[0]), ys = points.map((q) => q[1]);
  const pad = 0.06 * Math.max(Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys));
  const x0 = Math.min(...xs) - pad, y0 = Math.min(...ys) - pad, w = Math.max(...xs) - x0 + pad, hh = Math.max(...ys) - y0 + pad;
  const W = 420, H = Math.max(140, Math.min(220, W * hh / w)), scale = Math.min(W / w, H / hh);
  const sx = (q) => ((q[0] - x0) * scale).toFixed(1), syy = (q) => ((q[1] - y0) * scale).toFixed(1);
  const pt = (P) => { const q = view(P); return `${sx(q)},${syy(q)}`; };
  const colour = {left: "#2463eb", right: "#d97706"};
  let svg = `<svg viewBox="-12 -16 ${W + 24} ${(H + 40).toFixed(0)}" data-baseline-mm="${B}" data-distance-mm="${Z}" role="img" aria-label="the rig in 3-D">`;
  svg += `<polygon class="board" points="${board.map(pt).join(" ")}" fill="#1f9d55" fill-opacity="0.25" stroke="#1f9d55"/>`;
  for (const s of shapes) {
    const c = colour[s.name];
    svg += `<g class="frustum" data-camera="${s.name}"><polygon points="${s.far.map(pt).join(" ")}" fill="${c}" fill-opacity="0.06" stroke="${c}" stroke-opacity="0.5"/>` +
      s.far.map((f) => `<line x1="${sx(view(s.apex))}" y1="${syy(view(s.apex))}" x2="${sx(view(f))}" y2="${syy(view(f))}" stroke="${c}" stroke-opacity="0.45"/>`).join("") + "</g>";
  }
  const [l, r] = shapes.map((s) => view(s.apex));
  svg += `<line class="baseline" x1="${sx(l)}" y1="${syy(l)}" x2="${sx(r)}" y2="${syy(r)}" stroke="#20242c" stroke-width="3"/>`;
  for (const s of shapes) { const q = view(s.apex); const left = s.name === "left";  // labels outward: the two never overlap, however short B is
    svg += `<circle class="camera" data-camera="${s.name}" cx="${sx(q)}" cy="${syy(q)}" r="5" fill="${colour[s.name]}"/><text x="${(Number(sx(q)) + (left ? -8 : 8)).toFixed(1)}" y="${(Number(syy(q)) + 12).toFixed(1)}" text-anchor="${left ? "end" : "start"}">${s.name}</text>`; }
  const mid = view([0, 0, 0]), tip = view([0, 0, Z]);
  svg += `<text x="${sx(mid)}" y="${(Number(syy(mid)) - 8).toFixed(1)}" text-anchor="middle">B ${num(B, 0)} mm</text>` +
    `<text x="${sx(tip)}" y="${(Number(syy(tip)) - 6).toFixed(1)}" text-anchor="middle">board at Z ${num(Z, 0)} mm</text>`;
  box.innerHTML = svg + "</svg>";
}

function renderPlan(plan) {
  const c = plan.counts;
  const done = c.measured + c.failed + c.infeasible;
  $("counts").innerHTML = `<span><b>${c.measured}</b> measured</span><span><b>${c.failed}</b> failed</span>` +
    `<span><b>${c.infeasible}</b> infeasible</span><span><b>${c.remaining}</b> remaining</span><span class="muted">of ${c.total}</span>`;
  $("progress-bar").style.width = `${c.total ? (100 * done / c.total).toFixed(1) : 0}%`;
  $("eta").textContent = duration(plan.eta_s);
  $("eta-basis").textContent = plan.basis ? `ETA: ${plan.basis}` : "";
  $("step").textContent = plan.step || "";
  $("configs").innerHTML = plan.configs.map((cfg) => `<span class="cfg ${esc(cfg.status)}" ` +
    `title="${esc(cfg.config_id)}: ${esc(cfg.status)}${cfg.reason ? ` (${esc(cfg.reason)})` : ""}">${esc(cfg.config_id)}</span>`).join("");
}

function uncertainty(row) {
  if (row.U_expanded_mm !== undefined) return row.U_expanded_mm;
  return row.sigma_mm !== undefined ? 2 * row.sigma_mm : null;
}

// Numbers to their significant digits: an uncertainty to 2 significant digits, a value to the uncertainty's
// decimal place (GUM 7.2.6): 27.0217 +- 0.0324 reads 27.022 +- 0.032; a sigma of 2e-6 mm is not 0.0000.
function decimalsOf(u) {
  if (!(u > 0) || !Number.isFinite(u)) return null;
  return Math.max(0, 1 - Math.floor(Math.log10(u) + 1e-12));
}
function significant(u) {
  if (u === null || u === undefined || Number.isNaN(u)) return "–";
  if (u === 0) return "0";
  const d = decimalsOf(Math.abs(u));
  return d === null ? String(u) : Number(u).toFixed(d);
}
function toUncertainty(value, u, signed = false) {
  if (value === null || value === undefined || Number.isNaN(value)) return "–";
  const d = decimalsOf(u);
  const text = d === null ? Number(value).toPrecision(6) : Number(value).toFixed(d);
  return signed && value >= 0 ? `+${text}` : text;
}
window.liveFormat = {decimalsOf, significant, toUncertainty};

function renderResults(results, plan) {
  const hasU = results.some((r) => r.U_expanded_mm !== undefined || r.u_combined_mm !== undefined);
  const head = ["configuration", "B mm", "Z mm", "α °", "square mm", "error mm", "σ mm"].concat(hasU ? ["u_c mm", "U mm"] : []).concat(["RMS px"]);
  // Newest first: the result that just arrived is the one the operator looks for.
  const newest = [...results].sort((a, b) => (b.arrival || 0) - (a.arrival || 0));
  const body = newest.map((r) => {
    const cells = [esc(r.config_id), num(r.baseline_mm, 0), num(r.distance_mm, 0), num(r.alpha_deg, 1)];
    if (r.status !== "measured") {
      return `<tr data-config="${esc(r.config_id)}" data-status="${esc(r.status)}"><td>${cells.join("</td><td>")}</td>` +
        `<td class="${esc(r.status)}" colspan="${head.length - 4}">${esc(r.status)}${r.reason ? `: ${esc(r.reason)}` : ""}</td></tr>`;
    }
    const u = uncertainty(r);
    cells.push(toUncertainty(r.square_mean_mm, u), toUncertainty(r.error_mm, u, true), significant(r.sigma_mm));
    if (hasU) cells.push(significant(r.u_combined_mm), significant(r.U_expanded_mm));
    cells.push(significant(r.rms_px));
    return `<tr data-config="${esc(r.config_id)}" data-status="measured"><td>${cells.join("</td><td>")}</td></tr>`;
  }).join("");
  $("results-table").innerHTML = `<thead><tr>${head.map((h) => `<th>${h}</th>`).join("")}</tr></thead><tbody>${body}</tbody>`;
  renderPlot(results.filter((r) => r.status === "measured" && r.error_mm !== undefined), plan.varying || []);
}

const SERIES_COLOURS = ["#2463eb", "#d97706", "#1f9d55", "#c81e1e", "#7c3aed", "#0891b2", "#be185d", "#4b5565"];

function renderPlot(rows, varying) {
  const box = $("plot");
  const xKey = varying[0] || "distance_mm", seriesKey = varying[1];
  if (!rows.length) { box.innerHTML = `<p class="muted">Error against ${QUANTITY[xKey][0]} appears with the first measured configuration.</p>`; return; }
  const W = 420, H = 280, L = 58, R = 10, T = 14, B = 40;
  const xs = rows.map((r) => r[xKey]);
  const lows = rows.map((r) => r.error_mm - (uncertainty(r) || 0)), highs = rows.map((r) => r.error_mm + (uncertainty(r) || 0));
  let x0 = Math.min(...xs), x1 = Math.max(...xs);
  if (x0 === x1) { x0 -= 1; x1 += 1; }
  const pad = (x1 - x0) * 0.06; x0 -= pad; x1 += pad;
  let y0 = Math.min(0, ...lows), y1 = Math.max(0, ...highs);
  if (y0 === y1) { y0 -= 0.01; y1 += 0.01; }
  const ypad = (y1 - y0) * 0.08; y0 -= ypad; y1 += ypad;
  const sx = (x) => L + (x - x0) / (x1 - x0) * (W - L - R), sy = (y) => T + (y1 - y) / (y1 - y0) * (H - T - B);
  const ticks = (a, b, n) => { const step = niceStep((b - a) / n); const out = []; for (let v = Math.ceil(a / step) * step; v <= b + 1e-12; v += step) out.push(v); out.step = step; return out; };
  const yTicks = ticks(y0, y1, 5), xTicks = ticks(x0, x1, 6);
  let svg = `<svg viewBox="0 0 ${W} ${H}" role="img" aria-label="error against ${esc(QUANTITY[xKey][0])}">`;
  for (const v of yTicks) svg += `<line x1="${L}" x2="${W - R}" y1="${sy(v).toFixed(1)}" y2="${sy(v).toFixed(1)}" stroke="#eceff4"/><text x="${L - 4}" y="${(sy(v) + 4).toFixed(1)}" text-anchor="end">${fmtTick(v, yTicks.step)}</text>`;
  for (const v of xTicks) svg += `<text x="${sx(v).toFixed(1)}" y="${H - B + 14}" text-anchor="middle">${fmtTick(v, xTicks.step)}</text>`;
  svg += `<line x1="${L}" x2="${W - R}" y1="${sy(0).toFixed(1)}" y2="${sy(0).toFixed(1)}" stroke="#6b7385" stroke-dasharray="4 3"/>`;
  svg += `<text x="${(L + W - R) / 2}" y="${H - 6}" text-anchor="middle">${QUANTITY[xKey][0]} (${QUANTITY[xKey][1]})</text>`;
  svg += `<text transform="translate(12 ${(T + H - B) / 2}) rotate(-90)" text-anchor="middle">error (mm) ± ${rows.some((r) => r.U_expanded_mm !== undefined) ? "U" : "2σ"}</text>`;
  const groups = new Map(), legend = [];
  for (const r of rows) { const key = seriesKey ? r[seriesKey] : ""; if (!groups.has(key)) groups.set(key, []); groups.get(key).push(r); }
  [...groups.keys()].sort((a, b) => a - b).forEach((key, i) => {
    const colour = SERIES_COLOURS[i % SERIES_COLOURS.length];
    const dodge = (i - (groups.size - 1) / 2) * 4;  // px: series at the same x keep their error bars apart
    const px = (r) => (sx(r[xKey]) + dodge).toFixed(1);
    const points = groups.get(key).sort((a, b) => a[xKey] - b[xKey]);
    if (points.length > 1) svg += `<polyline fill="none" stroke="${colour}" stroke-width="1.5" points="${points.map((r) => `${px(r)},${sy(r.error_mm).toFixed(1)}`).join(" ")}"/>`;
    for (const r of points) {
      const u = uncertainty(r) || 0, x = px(r);
      svg += `<line x1="${x}" x2="${x}" y1="${sy(r.error_mm - u).toFixed(1)}" y2="${sy(r.error_mm + u).toFixed(1)}" stroke="${colour}"/>` +
        `<circle cx="${x}" cy="${sy(r.error_mm).toFixed(1)}" r="3.5" fill="${colour}"><title>${esc(r.config_id)}: ${r.error_mm.toFixed(4)} mm</title></circle>`;
    }
    // Below the plot, not in it: inside, the top-right corner is where the error bars of the largest x reach.
    if (seriesKey) legend.push(`<span style="color:${colour}">■ ${QUANTITY[seriesKey][0]} = ${fmtTick(key, 1)} ${QUANTITY[seriesKey][1]}</span>`);
  });
  box.innerHTML = svg + "</svg>" + (legend.length ? `<div class="legend series">${legend.join("")}</div>` : "");
}
function niceStep(raw) { const p = Math.pow(10, Math.floor(Math.log10(raw || 1))); const f = raw / p; return (f < 1.5 ? 1 : f < 3 ? 2 : f < 7 ? 5 : 10) * p; }
function fmtTick(v, step) {
  if (Math.abs(v) < 1e-12) return "0";
  const decimals = step ? Math.max(0, -Math.floor(Math.log10(step) + 1e-9)) : (Math.abs(v) >= 10 ? 0 : 2);
  return v.toFixed(Math.min(decimals, 6));
}

function renderLog(log) {
  $("log").innerHTML = log.map((e) => `<li class="${esc(e.level)}">${new Date(e.time * 1000).toLocaleTimeString()} ${esc(e.text)}</li>`).join("");
}

function renderPrompt(prompt, run) {
  const banner = $("prompt");
  banner.hidden = !prompt;
  // Which prompt the buttons answer (they send its id): a browser test or a script waits for the one it offered.
  if (prompt && prompt.id != null) banner.dataset.promptId = prompt.id;
  else delete banner.dataset.promptId;
  const accepts = prompt ? prompt.actions : [];
  for (const action of PROMPT_ACTIONS) {
    $(action).disabled = !TOKEN || !accepts.includes(action);
  }
  // The per-view error review (several lines: the chart) with its threshold and exclude controls.
  $("review-controls").hidden = !accepts.includes("set_threshold");
  if (prompt) {
    $("prompt-message").textContent = prompt.message;
    $("prompt-message").classList.toggle("chart", prompt.message.includes("\n"));
  }
  const live = ["running", "paused", "starting"].includes(run.status);
  $("pause").textContent = run.paused ? "Resume" : "Pause";
  $("pause").disabled = !TOKEN || !live;
  $("stop").disabled = !TOKEN || !live;
}

function render(next) {
  state = next;
  const run = state.run;
  $("name").textContent = run.name ? `· ${run.name}` : "";
  const status = state.prompt ? "waiting" : run.status;
  $("status").textContent = state.prompt ? "waiting for the operator" : run.status;
  $("status").className = `pill ${esc(status)}`;
  $("elapsed").textContent = duration(run.elapsed_s);
  document.title = `stereo-bench live · ${run.name || ""} · ${status}`;
  renderPrompt(state.prompt, run);
  renderPreview(state.preview);
  renderCoverage(state.coverage);
  renderCalibration(state.calibration);
  renderRig(state.rig);
  renderRig3d(state.rig, state.plan);
  renderPlan(state.plan);
  renderResults(state.results, state.plan);
  renderLog(state.log);
  if (run.resume_command && run.status === "interrupted") $("step").textContent = `stopped; resume with: ${run.resume_command}`;
  $("csv").hidden = !run.session;
  document.body.dataset.version = String(state.version);
}

function connect() {
  const source = new EventSource("/api/events");
  source.addEventListener("state", (event) => { $("connection").hidden = true; render(JSON.parse(event.data)); });
  // The newest preview alone (live previews come faster than whole states): the state's copy follows it.
  source.addEventListener("preview", (event) => {
    const meta = JSON.parse(event.data);
    if (state) state.preview = meta;
    renderPreview(meta);
  });
  source.onerror = () => { $("connection").hidden = state === null || ["success", "failed", "interrupted", "aborted"].includes(state.run.status); };
}
connect();
