/* impactcell charts: small hand-written SVG charts (a heat map and a line chart) with hover
 * and keyboard read-outs. No library: the page must work offline and load nothing foreign. */
"use strict";

(function () {
  // The SVG namespace is an identifier in the DOM API, never fetched.
  const NS = "http://www.w3.org/2000/svg";
  const PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"];
  // The dataset's outcome flag values, and 5: an irregular point flagged may_be_transient
  // (the page sets it from that variable).
  const OUTCOME_NAMES = ["linear", "periodic", "irregular", "unsettled", "failed",
    "irregular, may be transient (the impact-free response is admissible)"];
  // Irregular, may-be-transient, unsettled and failed points get the glyphs of the service's
  // own figures.
  const GLYPHS = { 2: "×", 3: "□", 4: "✖", 5: "◇" };
  const GLYPH_COLOURS = { 4: "#b42318", 5: "#d97706" };
  let uid = 0;

  function svg(tag, attrs, parent) {
    const el = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v !== undefined && v !== null) el.setAttribute(k, String(v));
    }
    if (parent) parent.appendChild(el);
    return el;
  }

  function text(parent, x, y, str, attrs) {
    const t = svg("text", Object.assign({ x, y }, attrs || {}), parent);
    t.textContent = str;
    return t;
  }

  /** A number for people: 4 significant digits, exponent only when it helps. */
  function fmt(v) {
    if (v === null || v === undefined) return "missing";
    if (typeof v !== "number") return String(v);
    if (!Number.isFinite(v)) return String(v);
    const a = Math.abs(v);
    if (a !== 0 && (a >= 1e5 || a < 1e-3)) return v.toExponential(2);
    return String(Number(v.toPrecision(4)));
  }

  const finite = (v) => typeof v === "number" && Number.isFinite(v);

  /** About n round tick values over [lo, hi]. */
  function niceTicks(lo, hi, n) {
    if (!(hi > lo)) return [lo];
    const raw = (hi - lo) / Math.max(1, n);
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) {
      out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
    }
    return out;
  }

  function mix(a, b, t) {
    const pa = [1, 3, 5].map((i) => parseInt(a.slice(i, i + 2), 16));
    const pb = [1, 3, 5].map((i) => parseInt(b.slice(i, i + 2), 16));
    return "#" + pa.map((c, i) => Math.round(c + (pb[i] - c) * t).toString(16).padStart(2, "0")).join("");
  }

  /** Diverging colours around the threshold: blue below (attenuating), red above. */
  function diverging(threshold, span) {
    return (v) => {
      if (!finite(v)) return "#e5e7eb";
      const t = Math.max(-1, Math.min(1, (v - threshold) / span));
      return t < 0 ? mix("#f7f7f7", "#2166ac", -t) : mix("#f7f7f7", "#b2182b", t);
    };
  }

  // One tooltip for the page (fixed position, follows the pointer or the keyboard cursor).
  function tooltip() {
    return document.getElementById("tooltip");
  }

  function showTip(str, clientX, clientY) {
    const tip = tooltip();
    if (!tip) return;
    tip.textContent = str;
    tip.hidden = false;
    const w = tip.offsetWidth;
    const left = clientX + 14 + w > window.innerWidth ? clientX - 14 - w : clientX + 14;
    tip.style.left = Math.max(4, left) + "px";
    tip.style.top = Math.max(4, clientY + 14) + "px";
  }

  function hideTip() {
    const tip = tooltip();
    if (tip) tip.hidden = true;
  }

  function frame(el, spec, height) {
    el.textContent = "";
    const width = Math.max(520, Math.min(1180, el.clientWidth || 900));
    const root = svg("svg", {
      viewBox: `0 0 ${width} ${height}`, width, height, tabindex: 0, role: "group",
      "aria-roledescription": "chart", "aria-label": spec.title,
      "data-chart": spec.kind,
    }, el);
    const readout = document.createElement("p");
    readout.className = "readout";
    readout.id = `readout-${++uid}`;
    readout.setAttribute("aria-live", "polite");
    readout.textContent = spec.hint || "Hover or use the arrow keys for values.";
    el.appendChild(readout);
    root.setAttribute("aria-describedby", readout.id);
    return { root, width, readout };
  }

  function keyed(root, move, show) {
    root.addEventListener("keydown", (ev) => {
      const d = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, 1], ArrowDown: [0, -1],
        Home: [-1e9, 0], End: [1e9, 0] }[ev.key];
      if (!d) return;
      ev.preventDefault();
      move(d[0], d[1]);
      show(true);
    });
    root.addEventListener("blur", hideTip);
    root.addEventListener("mouseleave", hideTip);
  }

  /** Where a value lies on a grid, in fractional index units (for band edges). */
  function fractionalIndex(values, v) {
    for (let i = 0; i < values.length - 1; i++) {
      const a = values[i], b = values[i + 1];
      if ((v >= a && v <= b) || (v <= a && v >= b)) return i + (b === a ? 0 : (v - a) / (b - a));
    }
    return v <= values[0] ? 0 : values.length - 1;
  }

  /**
   * A heat map of z over x × y (cells in grid order), hatched where `attenuating`, band
   * edges marked, irregular (×), may-be-transient (◇), unsettled (□) and failed (✖) points
   * marked.
   */
  function heatmap(el, spec) {
    const xs = spec.x.values, ys = spec.y ? spec.y.values : [null];
    const nx = xs.length, ny = ys.length;
    const rowH = Math.max(14, Math.min(48, Math.floor(320 / ny)));
    const M = { l: 78, r: 96, t: 12, b: 50 };
    const height = M.t + rowH * ny + M.b;
    const { root, width, readout } = frame(el, spec, height);
    const pw = width - M.l - M.r, cw = pw / nx;
    const vals = spec.z.flat().filter(finite);
    const thr = spec.threshold || 0;
    const span = Math.max(1e-9, ...vals.map((v) => Math.abs(v - thr)));
    const colour = diverging(thr, span);
    const id = `hatch-${++uid}`;
    const defs = svg("defs", {}, root);
    const pat = svg("pattern", { id, width: 6, height: 6, patternUnits: "userSpaceOnUse",
      patternTransform: "rotate(45)" }, defs);
    svg("line", { x1: 0, y1: 0, x2: 0, y2: 6, stroke: "#000", "stroke-opacity": 0.45,
      "stroke-width": 1.2 }, pat);
    const rowY = (j) => M.t + (ny - 1 - j) * rowH; // the first y value at the bottom
    const cells = svg("g", { "data-role": "cells" }, root);
    const glyphs = svg("g", { "font-size": Math.max(8, Math.min(14, Math.min(cw, rowH) * 0.8)),
      "text-anchor": "middle", "dominant-baseline": "central", "pointer-events": "none" }, root);
    let count = 0;
    for (let j = 0; j < ny; j++) {
      for (let i = 0; i < nx; i++) {
        const v = spec.z[j][i];
        const x = M.l + i * cw, y = rowY(j);
        svg("rect", { x, y, width: cw + 0.5, height: rowH + 0.5, fill: colour(v),
          "data-value": finite(v) ? v : "" }, cells);
        if (finite(v)) count++;
        if (spec.attenuating && spec.attenuating[j] && spec.attenuating[j][i]) {
          svg("rect", { x, y, width: cw + 0.5, height: rowH + 0.5, fill: `url(#${id})`,
            "pointer-events": "none" }, cells);
        }
        const o = spec.outcome ? spec.outcome[j][i] : null;
        const g = GLYPHS[o];
        if (g) text(glyphs, x + cw / 2, y + rowH / 2, g, { fill: GLYPH_COLOURS[o] || "#111" });
      }
    }
    root.setAttribute("data-points", count);
    // Band edges: short black bars where each band starts and stops (interpolated in x).
    const edgeG = svg("g", { stroke: "#000", "stroke-width": 2.5, "pointer-events": "none" }, root);
    for (const e of spec.edges || []) {
      const j = spec.y ? ys.findIndex((y) => Math.abs(y - e.y) <= 1e-9 * Math.max(1, Math.abs(y))) : 0;
      if (j < 0) continue;
      for (const band of e.bands || []) {
        for (const b of band) {
          if (!finite(b)) continue;
          const px = M.l + (fractionalIndex(xs, b) + 0.5) * cw;
          svg("line", { x1: px, x2: px, y1: rowY(j) + 2, y2: rowY(j) + rowH - 2 }, edgeG);
        }
      }
    }
    // Axes: tick labels at up to 8 grid values on x, every row (or every k-th) on y.
    const axis = svg("g", { "font-size": 12, fill: "#333" }, root);
    // Round x ticks placed between the grid values (cells are in grid order, equal widths).
    const xmin = Math.min(...xs), xmax = Math.max(...xs);
    for (const t of nx > 1 ? niceTicks(xmin, xmax, Math.min(8, nx)) : xs) {
      const px = M.l + (fractionalIndex(xs, t) + 0.5) * cw;
      svg("line", { x1: px, x2: px, y1: M.t + rowH * ny, y2: M.t + rowH * ny + 4, stroke: "#333" }, axis);
      text(axis, px, M.t + rowH * ny + 16, fmt(t), { "text-anchor": "middle" });
    }
    text(axis, M.l + pw / 2, height - 8, spec.x.label, { "text-anchor": "middle", "font-weight": 600 });
    const ystep = Math.max(1, Math.ceil(ny / Math.max(1, Math.floor(rowH * ny / 18))));
    for (let j = 0; j < ny && spec.y; j += ystep) {
      text(axis, M.l - 6, rowY(j) + rowH / 2, fmt(ys[j]), { "text-anchor": "end", "dominant-baseline": "central" });
    }
    if (spec.y) {
      const t = text(axis, 14, M.t + rowH * ny / 2, spec.y.label, { "text-anchor": "middle", "font-weight": 600 });
      t.setAttribute("transform", `rotate(-90 14 ${M.t + rowH * ny / 2})`);
    }
    // Colour bar
    const gid = `grad-${++uid}`;
    const grad = svg("linearGradient", { id: gid, x1: 0, y1: 1, x2: 0, y2: 0 }, defs);
    [[0, -1], [0.5, 0], [1, 1]].forEach(([o, t]) => svg("stop", { offset: o, "stop-color": colour(thr + t * span) }, grad));
    const bx = width - M.r + 18, bh = Math.max(40, rowH * ny);
    svg("rect", { x: bx, y: M.t, width: 14, height: bh, fill: `url(#${gid})`, stroke: "#999" }, root);
    text(axis, bx + 18, M.t + 8, fmt(thr + span), { "font-size": 11 });
    text(axis, bx + 18, M.t + bh / 2 + 4, fmt(thr), { "font-size": 11 });
    text(axis, bx + 18, M.t + bh, fmt(thr - span), { "font-size": 11 });
    text(axis, bx - 4, M.t + bh + 16, spec.zLabel, { "font-size": 11 });

    // Read-out: the cell under the pointer or the keyboard cursor.
    const cursor = svg("rect", { width: cw, height: rowH, fill: "none", stroke: "#d97706",
      "stroke-width": 2, visibility: "hidden", "pointer-events": "none" }, root);
    let ci = 0, cj = 0;
    function describe(i, j) {
      const o = spec.outcome ? spec.outcome[j][i] : null;
      const parts = [`${spec.x.label} = ${fmt(xs[i])}`];
      if (spec.y) parts.push(`${spec.y.label} = ${fmt(ys[j])}`);
      let s = parts.join(", ") + `: ${spec.zLabel} = ${fmt(spec.z[j][i])}`;
      if (spec.attenuating && spec.attenuating[j][i]) s += " (in a band)";
      if (o === -1) s += "; not computed yet";
      else if (o === -2) s += "; not sampled by its adaptive line";
      else if (o !== null && o !== undefined && OUTCOME_NAMES[o]) s += `; ${OUTCOME_NAMES[o]}`;
      const why = spec.reason ? spec.reason[j][i] : "";
      if (why) s += `\n${why}`;
      return s;
    }
    function show(fromKeyboard, ev) {
      cursor.setAttribute("x", M.l + ci * cw);
      cursor.setAttribute("y", rowY(cj));
      cursor.setAttribute("visibility", "visible");
      const s = describe(ci, cj);
      readout.textContent = s;
      if (ev) showTip(s, ev.clientX, ev.clientY);
      else {
        const r = cursor.getBoundingClientRect();
        showTip(s, r.right, r.bottom);
      }
    }
    root.addEventListener("mousemove", (ev) => {
      const r = root.getBoundingClientRect();
      const sx = (ev.clientX - r.left) * (width / r.width), sy = (ev.clientY - r.top) * (height / r.height);
      const i = Math.floor((sx - M.l) / cw), j = ny - 1 - Math.floor((sy - M.t) / rowH);
      if (i < 0 || i >= nx || j < 0 || j >= ny) { hideTip(); return; }
      ci = i; cj = j;
      show(false, ev);
    });
    keyed(root, (di, dj) => {
      ci = Math.max(0, Math.min(nx - 1, ci + di));
      cj = Math.max(0, Math.min(ny - 1, cj + dj));
    }, show);
    return root;
  }

  /** Lines of several series over x, gaps where values are missing, outcome glyphs. */
  function lineChart(el, spec) {
    const xs = spec.x.values;
    const M = { l: 66, r: 18, t: 14, b: 50 };
    const height = spec.height || 270;
    const { root, width, readout } = frame(el, spec, height);
    const pw = width - M.l - M.r, ph = height - M.t - M.b;
    const all = spec.series.flatMap((s) => s.values.filter(finite));
    if (spec.refLine !== undefined) all.push(spec.refLine);
    let lo = Math.min(...all), hi = Math.max(...all);
    if (!all.length) { lo = 0; hi = 1; }
    if (hi === lo) { lo -= 1; hi += 1; }
    const pad = (hi - lo) * 0.05;
    lo -= pad; hi += pad;
    const xlo = Math.min(...xs), xhi = Math.max(...xs);
    const X = (v) => M.l + (xhi === xlo ? pw / 2 : (v - xlo) / (xhi - xlo) * pw);
    const Y = (v) => M.t + ph - (v - lo) / (hi - lo) * ph;
    const axis = svg("g", { "font-size": 12, fill: "#333" }, root);
    const grid = svg("g", { stroke: "#e5e7eb" }, root);
    for (const t of niceTicks(lo, hi, 6)) {
      svg("line", { x1: M.l, x2: M.l + pw, y1: Y(t), y2: Y(t) }, grid);
      text(axis, M.l - 6, Y(t), fmt(t), { "text-anchor": "end", "dominant-baseline": "central" });
    }
    for (const t of niceTicks(xlo, xhi, 8)) {
      svg("line", { x1: X(t), x2: X(t), y1: M.t, y2: M.t + ph }, grid);
      text(axis, X(t), M.t + ph + 16, fmt(t), { "text-anchor": "middle" });
    }
    svg("rect", { x: M.l, y: M.t, width: pw, height: ph, fill: "none", stroke: "#999" }, root);
    if (spec.refLine !== undefined && spec.refLine >= lo && spec.refLine <= hi) {
      svg("line", { x1: M.l, x2: M.l + pw, y1: Y(spec.refLine), y2: Y(spec.refLine), stroke: "#555",
        "stroke-dasharray": "2 3" }, root);
    }
    text(axis, M.l + pw / 2, height - 8, spec.x.label, { "text-anchor": "middle", "font-weight": 600 });
    const yl = text(axis, 14, M.t + ph / 2, spec.yLabel, { "text-anchor": "middle", "font-weight": 600 });
    yl.setAttribute("transform", `rotate(-90 14 ${M.t + ph / 2})`);

    let count = 0;
    const lines = svg("g", { fill: "none", "stroke-width": 1.8 }, root);
    const marks = svg("g", { "font-size": 12, "text-anchor": "middle", "dominant-baseline": "central" }, root);
    spec.series.forEach((s, k) => {
      s.color = s.color || PALETTE[k % PALETTE.length];
      let d = "", pen = false;
      s.values.forEach((v, i) => {
        if (!finite(v)) { if (!(s.bridge && s.bridge[i])) pen = false; return; }
        d += `${pen ? "L" : "M"}${X(xs[i]).toFixed(1)},${Y(v).toFixed(1)}`;
        pen = true;
        count++;
      });
      svg("path", { d, stroke: s.color, "stroke-dasharray": s.dashed ? "6 4" : null,
        "data-series": s.label }, lines);
      s.values.forEach((v, i) => {
        const o = s.outcome ? s.outcome[i] : null;
        if (!finite(v)) { // failed points on the bottom strip, as in the service's figures
          if (o === 4) text(marks, X(xs[i]), M.t + ph - 8, GLYPHS[4], { fill: "#b42318" });
          return;
        }
        if (GLYPHS[o]) text(marks, X(xs[i]), Y(v), GLYPHS[o], { fill: GLYPH_COLOURS[o] || s.color });
        else if (xs.length <= 120 && !s.dashed) svg("circle", { cx: X(xs[i]), cy: Y(v), r: 2.2, fill: s.color }, marks);
      });
    });
    root.setAttribute("data-points", count);

    const legend = document.createElement("ul");
    legend.className = "legend";
    for (const s of spec.series) {
      const li = document.createElement("li");
      const sw = document.createElement("span");
      sw.className = "swatch";
      sw.style.background = s.dashed ? "transparent" : s.color;
      sw.style.borderTop = s.dashed ? `3px dashed ${s.color}` : "";
      sw.setAttribute("aria-hidden", "true");
      li.append(sw, s.label);
      legend.appendChild(li);
    }
    el.insertBefore(legend, readout);

    const rule = svg("line", { y1: M.t, y2: M.t + ph, stroke: "#d97706", "stroke-width": 1.5,
      visibility: "hidden", "pointer-events": "none" }, root);
    let ci = 0;
    function describe(i) {
      const rows = spec.series.map((s) => {
        const o = s.outcome ? s.outcome[i] : null;
        const tag = o === -1 ? " (not computed yet)" : o >= 2 && OUTCOME_NAMES[o] ? ` (${OUTCOME_NAMES[o]})` : "";
        return `${s.label}: ${fmt(s.values[i])}${tag}`;
      });
      return `${spec.x.label} = ${fmt(xs[i])}\n${rows.join("\n")}`;
    }
    function show(fromKeyboard, ev) {
      rule.setAttribute("x1", X(xs[ci]));
      rule.setAttribute("x2", X(xs[ci]));
      rule.setAttribute("visibility", "visible");
      const s = describe(ci);
      readout.textContent = s.replace(/\n/g, "; ");
      if (ev) showTip(s, ev.clientX, ev.clientY);
      else {
        const r = root.getBoundingClientRect();
        showTip(s, r.left + X(xs[ci]) * (r.width / width), r.top + M.t * (r.height / height));
      }
    }
    root.addEventListener("mousemove", (ev) => {
      const r = root.getBoundingClientRect();
      const sx = (ev.clientX - r.left) * (width / r.width);
      if (sx < M.l - 4 || sx > M.l + pw + 4) { hideTip(); return; }
      let best = 0;
      xs.forEach((x, i) => { if (Math.abs(X(x) - sx) < Math.abs(X(xs[best]) - sx)) best = i; });
      ci = best;
      show(false, ev);
    });
    keyed(root, (di) => { ci = Math.max(0, Math.min(xs.length - 1, ci + di)); }, show);
    return root;
  }

  window.ImpactCharts = { heatmap, lineChart, fmt, OUTCOME_NAMES };
})();
