/* impactcell web page: a single page over the service's JSON API, routed by the URL hash.
 *   #/                 studies, newest first, live
 *   #/studies/<id>     one study: status, charts, downloads, actions
 *   #/submit           paste or upload a study file
 *   #/regressions      nightly regression reports
 * The token (when the service has one) is asked for once and kept in sessionStorage. */
"use strict";

(function () {
  const TOKEN_KEY = "impactcell.token";
  const STATUSES = ["queued", "running", "waiting", "finished", "failed", "cancelled"];
  // A study a process runs or will run (cancel applies; the page keeps polling it).
  const ACTIVE = ["queued", "running", "waiting"];
  const POLL_MS = 2000;
  const C = window.ImpactCharts;
  const fmt = C.fmt;
  // Axis and variable names as the paper writes them (service.studies.variables has the rest).
  const SYMBOLS = { cells: "cells N", gamma_r: "γ_r", gap: "gap g̃", g1: "g1", g2: "g2", theta: "θ", sigma: "σ",
    gamma_s: "γ_s", xi: "ξ", frequency_hz: "f (Hz)", initial: "initial state", direction: "direction",
    gap_m: "gap", gap1_m: "gap 1", gap2_m: "gap 2", length_m: "length", width_m: "width", thickness_m: "thickness",
    density_kg_m3: "density", youngs_modulus_pa: "E", outer_mass_kg: "outer mass", spring_n_m: "spring stiffness",
    damping_ratio: "damping ratio", base_amplitude_m: "U_g", base_acceleration_m_s2: "base acceleration" };
  // SI units with a prefix, as the figures write them (service/analysis/plots.py, _PREFIXES):
  // the largest prefix whose value is at least 0.1, so 0.0005 m reads 0.5 mm.
  const PREFIXES = { m: [["m", 1], ["mm", 1e-3], ["µm", 1e-6], ["nm", 1e-9]],
    Pa: [["GPa", 1e9], ["MPa", 1e6], ["kPa", 1e3], ["Pa", 1]], kg: [["kg", 1], ["g", 1e-3], ["mg", 1e-6]],
    "N m-1": [["kN m-1", 1e3], ["N m-1", 1]] };
  const MAP_VARIABLES = { transmittance_db: "Γ (dB)", transmittance_linear_db: "Γ_lin, no stops (dB)",
    impact_effect_db: "Γ − Γ_lin, impact effect (dB)" };
  const CURVE_VARIABLES = { transmittance_db: "Γ (dB), Γ_lin dashed", impact_effect_db: "Γ − Γ_lin (dB)",
    transmittance_linear_db: "Γ_lin (dB)", amplitude: "amplitude A_s" };
  const Y_LABELS = { transmittance_db: "Γ (dB)", impact_effect_db: "Γ − Γ_lin (dB)",
    transmittance_linear_db: "Γ_lin (dB)", amplitude: "A_s / B", theta_eff: "θ_eff", theta_eff_slope: "θ_ps" };
  // θ_eff is the effective mass (first harmonic, docs/model.md §6); θ_ps weighs every harmonic
  // and is not an effective mass where impacts put motion into the harmonics.
  const MASS_VARIABLES = { theta_eff: "effective mass θ_eff (first harmonic)",
    theta_eff_slope: "phase-portrait ratio θ_ps (all harmonics; θ_eff only without impacts)" };
  const TRANSIENT = 5; // charts.js: an irregular point flagged may_be_transient
  // The example study: the default solver, so that every point settles (linear, periodic or
  // irregular; tests/service/web/test_page.py runs it), in a few seconds.
  const EXAMPLE = [
    "name: my-first-study",
    "description: Γ over frequency at two gaps",
    "grid:",
    "  gamma_r: {start: 0.5, stop: 3.0, num: 12}",
    "  gap: [0.1, 0.5]",
    "  theta: 0.3",
    "  sigma: 0.05",
    "  gamma_s: 1.0",
    "",
  ].join("\n");

  const view = document.getElementById("view");
  let generation = 0; // bumped on every route: stale polls and fetches stop themselves

  // ------------------------------------------------------------------ small DOM helpers

  /** h("tag", {attr: value, onclick: fn, text: "..."}, children...) */
  function h(tag, attrs, ...children) {
    const el = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === undefined || v === null || v === false) continue;
      if (k === "text") el.textContent = v;
      else if (k === "class") el.className = v;
      else if (k.startsWith("on")) el.addEventListener(k.slice(2), v);
      else if (k in el && typeof v !== "string") el[k] = v;
      else el.setAttribute(k, v === true ? "" : v);
    }
    for (const c of children.flat()) {
      if (c === null || c === undefined || c === false) continue;
      el.append(c instanceof Node ? c : String(c));
    }
    return el;
  }

  const sym = (name) => SYMBOLS[name] || name;

  /** [factor, prefixed units] of an axis in SI `units` over `values` ([1, units] without a prefix). */
  function prefixed(units, values) {
    const choices = PREFIXES[units];
    if (!choices) return [1, units || ""];
    const big = Math.max(0, ...values.filter((v) => typeof v === "number" && Number.isFinite(v)).map(Math.abs));
    for (const [text, factor] of choices) if (big / factor >= 0.1) return [factor, text];
    const [text, factor] = choices[choices.length - 1];
    return [factor, text];
  }
  const announce = (msg) => { document.getElementById("announce").textContent = msg; };

  function badge(status) {
    return h("span", { class: `status status-${status}`, text: status });
  }

  function duration(s) {
    if (s === null || s === undefined || !Number.isFinite(s)) return "–";
    if (s < 60) return `${s.toFixed(s < 10 ? 1 : 0)} s`;
    if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
    return `${Math.floor(s / 3600)} h ${Math.round((s % 3600) / 60)} min`;
  }

  const rate = (v) => String(Number(v.toPrecision(v >= 100 ? 4 : 2)));

  function when(iso) {
    if (!iso) return "–";
    const d = new Date(iso);
    return Number.isNaN(d.getTime()) ? iso : d.toLocaleString();
  }

  function setTitle(text) {
    document.title = `${text} · impactcell`;
  }

  /** A fresh view: its heading gets the focus, so a screen reader starts there. */
  function page(title, navKey) {
    generation++;
    view.textContent = "";
    document.getElementById("tooltip").hidden = true; // a chart's, left by the last route
    window.scrollTo(0, 0);
    setTitle(title);
    for (const a of document.querySelectorAll("[data-nav]")) {
      if (a.dataset.nav === navKey) a.setAttribute("aria-current", "page");
      else a.removeAttribute("aria-current");
    }
    const h1 = h("h1", { tabindex: "-1", text: title });
    view.append(h1);
    return { gen: generation, h1 };
  }

  const alive = (gen) => gen === generation;

  // ------------------------------------------------------------------ API and token

  class ApiError extends Error {
    constructor(status, detail, problems) {
      super(detail);
      this.status = status;
      this.problems = problems || null;
    }
  }

  let tokenPrompt = null; // one dialog for every request that got a 401

  function askToken(why) {
    if (tokenPrompt) return tokenPrompt;
    const dialog = document.getElementById("token-dialog");
    const form = document.getElementById("token-form");
    const input = document.getElementById("token-input");
    document.getElementById("token-why").textContent = why;
    input.value = "";
    tokenPrompt = new Promise((resolve) => {
      const done = (ev) => {
        ev.preventDefault();
        const token = input.value.trim();
        if (!token) return;
        sessionStorage.setItem(TOKEN_KEY, token);
        form.removeEventListener("submit", done);
        dialog.close();
        tokenPrompt = null;
        document.getElementById("forget-token").hidden = false;
        resolve();
      };
      form.addEventListener("submit", done);
    });
    dialog.showModal();
    input.focus();
    return tokenPrompt;
  }

  /** fetch() with the token; a 401 asks for the token and tries again. */
  async function api(path, options) {
    const opts = Object.assign({}, options || {});
    const headers = new Headers(opts.headers || {});
    const token = sessionStorage.getItem(TOKEN_KEY);
    if (token) headers.set("Authorization", `Bearer ${token}`);
    // The service takes a state change only with a JSON or YAML body type (its guard against
    // pages of other sites), also when there is no body (cancel, resume, delete).
    if ((opts.method || "GET").toUpperCase() !== "GET" && !headers.has("Content-Type")) {
      headers.set("Content-Type", "application/json");
    }
    opts.headers = headers;
    const r = await fetch(path, opts);
    if (r.status === 401) {
      await askToken(token
        ? "The service refused this token. Enter its API token (IMPACTCELL_API_TOKEN) again."
        : "This service needs its API token (IMPACTCELL_API_TOKEN). It is kept in this tab only, until you close it.");
      return api(path, options);
    }
    return r;
  }

  async function errorOf(r) {
    let body = null;
    try { body = await r.json(); } catch (e) { /* not JSON */ }
    const detail = body && body.detail ? body.detail : `${r.status} ${r.statusText}`;
    return new ApiError(r.status, detail, body && body.problems);
  }

  async function getJSON(path, options) {
    const r = await api(path, options);
    if (!r.ok) throw await errorOf(r);
    return r.status === 204 ? null : r.json();
  }

  function query(params) {
    const q = new URLSearchParams();
    for (const [k, v] of Object.entries(params)) {
      if (v !== undefined && v !== null && v !== "") q.set(k, String(v));
    }
    const s = q.toString();
    return s ? `?${s}` : "";
  }

  /** Download a file of the API (with the token, so not a plain link): fetch, then save. */
  async function download(path, fallback, status) {
    status.textContent = `Downloading ${fallback}…`;
    try {
      const r = await api(path);
      if (!r.ok) throw await errorOf(r);
      const blob = await r.blob();
      const cd = r.headers.get("content-disposition") || "";
      const m = /filename="?([^";]+)"?/.exec(cd);
      const a = h("a", { href: URL.createObjectURL(blob), download: m ? m[1] : fallback });
      document.body.append(a);
      a.click();
      a.remove();
      setTimeout(() => URL.revokeObjectURL(a.href), 30000);
      status.textContent = `Downloaded ${m ? m[1] : fallback} (${(blob.size / 1024).toFixed(0)} KB).`;
    } catch (e) {
      status.textContent = `Download failed: ${e.message}`;
    }
  }

  // ------------------------------------------------------------------ YAML of a definition

  function yamlScalar(v) {
    if (v === null) return "null";
    if (typeof v === "number" || typeof v === "boolean") return String(v);
    const s = String(v);
    return /^[\w.\-/ ()+]+$/.test(s) && !/^(true|false|null|yes|no|on|off|[-+.\d].*)$/i.test(s) && s.trim() === s
      ? s : JSON.stringify(s);
  }

  /** The canonical definition (JSON) as YAML, the study-file format people write. */
  function toYaml(v, indent) {
    const pad = "  ".repeat(indent || 0);
    if (Array.isArray(v)) {
      if (v.every((x) => x === null || typeof x !== "object")) return `[${v.map(yamlScalar).join(", ")}]`;
      return "\n" + v.map((x) => `${pad}- ${toYaml(x, (indent || 0) + 1).replace(/^\n\s*/, "")}`).join("\n");
    }
    if (v && typeof v === "object") {
      const keys = Object.keys(v);
      if (!keys.length) return "{}";
      return "\n" + keys.map((k) => {
        const inner = toYaml(v[k], (indent || 0) + 1);
        return `${pad}${k}:${inner.startsWith("\n") ? "" : " "}${inner}`;
      }).join("\n");
    }
    return yamlScalar(v);
  }

  // ------------------------------------------------------------------ #/ : the studies

  function homeView() {
    const { gen } = page("Studies", "studies");
    const statusSel = h("select", { id: "filter-status" },
      h("option", { value: "", text: "any" }), STATUSES.map((s) => h("option", { value: s, text: s })));
    const nameIn = h("input", { id: "filter-name", type: "search", placeholder: "part of a name", maxlength: "200" });
    const summary = h("p", { id: "studies-summary", "aria-live": "polite", class: "muted", text: "Loading studies…" });
    const tbody = h("tbody");
    const table = h("table", { id: "studies" },
      h("caption", { class: "visually-hidden", text: "Studies, newest first" }),
      h("thead", {}, h("tr", {},
        h("th", { scope: "col", text: "Name" }), h("th", { scope: "col", text: "Status" }),
        h("th", { scope: "col", text: "Progress" }), h("th", { scope: "col", class: "num", text: "Points" }),
        h("th", { scope: "col", class: "num", text: "Rate" }), h("th", { scope: "col", class: "num", text: "ETA" }),
        h("th", { scope: "col", text: "Submitted" }))),
      tbody);
    view.append(
      h("form", { class: "toolbar", role: "search", "aria-label": "Filter studies", onsubmit: (e) => { e.preventDefault(); refresh(); } },
        h("div", { class: "field" }, h("label", { for: "filter-status", text: "Status" }), statusSel),
        h("div", { class: "field" }, h("label", { for: "filter-name", text: "Name contains" }), nameIn),
        h("a", { href: "#/submit", text: "Submit a study…" })),
      summary, h("div", { class: "table-wrap" }, table));

    const rows = new Map();
    let timer = null, lastSummary = "";
    function row(s) {
      const cells = {
        name: h("td", {}, h("a", { href: `#/studies/${s.id}` })),
        status: h("td"), progress: h("td"), points: h("td", { class: "num" }),
        rate: h("td", { class: "num" }), eta: h("td", { class: "num" }), submitted: h("td"),
      };
      const tr = h("tr", { "data-id": s.id }, Object.values(cells));
      tr.cells_ = cells;
      return tr;
    }
    function fill(tr, s) {
      const c = tr.cells_;
      c.name.firstChild.textContent = s.name;
      c.status.replaceChildren(badge(s.status),
        s.queue_position ? h("span", { class: "muted", text: ` #${s.queue_position} in queue` }) : "");
      const pct = Math.round(s.progress * 100);
      c.progress.replaceChildren(h("progress", { max: 1, value: s.progress, "aria-label": `${s.name}: ${pct} %` }), ` ${pct} %`);
      c.points.textContent = `${s.points_done.toLocaleString()} / ${s.points_total.toLocaleString()}` +
        (s.points_failed ? ` (${s.points_failed} failed)` : "");
      c.rate.textContent = s.rate_points_per_s ? `${rate(s.rate_points_per_s)} points/s` : "–";
      c.eta.textContent = s.eta_s !== null && s.eta_s !== undefined ? duration(s.eta_s) : "–";
      c.submitted.textContent = when(s.submitted_at);
    }
    async function refresh() {
      clearTimeout(timer);
      try {
        const data = await getJSON(`studies${query({ status: statusSel.value, name: nameIn.value.trim(), limit: 200 })}`);
        if (!alive(gen)) return;
        const ids = data.items.map((s) => s.id);
        const same = ids.length === tbody.children.length && ids.every((id, i) => tbody.children[i].dataset.id === id);
        if (!same) { // rebuilt only when the list changed, so the keyboard focus stays put
          const kept = new Map();
          for (const s of data.items) kept.set(s.id, rows.get(s.id) || row(s));
          rows.clear();
          kept.forEach((v, k) => rows.set(k, v));
          tbody.replaceChildren(...kept.values());
        }
        data.items.forEach((s) => fill(rows.get(s.id), s));
        const counts = {};
        data.items.forEach((s) => { counts[s.status] = (counts[s.status] || 0) + 1; });
        const parts = STATUSES.filter((s) => counts[s]).map((s) => `${counts[s]} ${s}`);
        const text = data.total === 0 ? "No studies yet. Submit one to start."
          : `${data.total} ${data.total === 1 ? "study" : "studies"}${parts.length ? ": " + parts.join(", ") : ""}` +
            (data.total > data.items.length ? ` (newest ${data.items.length} shown)` : "");
        if (text !== lastSummary) summary.textContent = lastSummary = text;
      } catch (e) {
        if (!alive(gen)) return;
        summary.textContent = `Could not load the studies: ${e.message}`;
      }
      if (alive(gen)) timer = setTimeout(refresh, document.hidden ? POLL_MS * 5 : POLL_MS);
    }
    statusSel.addEventListener("change", refresh);
    let typing = null;
    nameIn.addEventListener("input", () => { clearTimeout(typing); typing = setTimeout(refresh, 300); });
    refresh();
  }

  // ------------------------------------------------------------------ #/studies/<id>

  function studyView(id) {
    const { gen, h1 } = page("Study", "studies");
    const live = h("p", { id: "study-live", "aria-live": "polite", class: "muted" });
    const actionsMsg = h("p", { id: "action-message", role: "status" });
    const cancelBtn = h("button", { type: "button", id: "cancel", text: "Cancel", onclick: () => act("cancel") });
    const resumeBtn = h("button", { type: "button", id: "resume", text: "Resume", onclick: () => act("resume") });
    const deleteBtn = h("button", { type: "button", id: "delete", class: "danger", text: "Delete…", onclick: () => act("delete") });
    const facts = h("dl", { class: "facts", id: "facts" });
    const failures = h("div", { id: "failures" });
    const results = h("section", { id: "results", "aria-labelledby": "results-title" },
      h("h2", { id: "results-title", text: "Results" }),
      h("p", { class: "muted", id: "results-note", text: "No finished points yet." }));
    const defPre = h("pre", { id: "definition", tabindex: "0", "aria-label": "Study definition (YAML)" });
    const dlStatus = h("p", { role: "status", class: "muted" });
    view.append(
      h("p", { class: "muted" }, "id ", h("code", { text: id })),
      h("div", { class: "actions" }, cancelBtn, resumeBtn, deleteBtn), actionsMsg,
      h("section", { "aria-labelledby": "status-title" }, h("h2", { id: "status-title", text: "Status" }), live, facts, failures),
      results,
      h("section", { "aria-labelledby": "dl-title" }, h("h2", { id: "dl-title", text: "Downloads" }),
        h("div", { class: "downloads", id: "downloads" }), dlStatus),
      h("section", { "aria-labelledby": "def-title" }, h("h2", { id: "def-title", text: "Definition" }), defPre));

    let rec = null, timer = null, charted = -1, chartsAt = 0, ctl = null;

    function render(r) {
      rec = r;
      h1.textContent = r.name;
      setTitle(r.name);
      const active = ACTIVE.includes(r.status);
      cancelBtn.disabled = !active;
      resumeBtn.disabled = !(r.status === "cancelled" || r.status === "failed");
      const pct = Math.round(r.progress * 100);
      const line = `${r.status}, ${pct} % (${r.points_done} of ${r.points_total} points)` +
        (r.eta_s ? `, about ${duration(r.eta_s)} left` : "");
      if (live.textContent !== line) live.textContent = line;
      const f = [
        ["Status", badge(r.status)],
        ["Progress", [h("progress", { max: 1, value: r.progress, "aria-label": `progress ${pct} %` }), ` ${pct} %`]],
        ["Points", `${r.points_done.toLocaleString()} done of ${r.points_total.toLocaleString()}`],
        ["Failed / irregular / unsettled", `${r.points_failed} / ${r.points_irregular} / ${r.points_unsettled}`],
        ["Rate", r.rate_points_per_s ? `${rate(r.rate_points_per_s)} points/s` : "–"],
        ["ETA", r.eta_s !== null && r.eta_s !== undefined ? duration(r.eta_s) : "–"],
        ["Submitted", when(r.submitted_at)], ["Started", when(r.started_at)],
        ["Finished", when(r.finished_at)], ["Running time", duration(r.wall_s)],
      ];
      if (r.queue_position) f.push(["Queue position", String(r.queue_position)]);
      if (r.error) f.push(["Error", h("span", { class: "error", text: r.error })]);
      if (r.hint) f.push(["What next", r.hint]);
      facts.replaceChildren(...f.flatMap(([k, v]) => [h("dt", { text: k }), h("dd", {}, v)]));
      failures.replaceChildren();
      if (r.failures && r.failures.length) {
        failures.append(h("h3", { text: `Failed points (${r.points_failed}; a sample)` }),
          h("div", { class: "table-wrap" }, h("table", {},
            h("thead", {}, h("tr", {}, h("th", { scope: "col", text: "Point" }), h("th", { scope: "col", text: "Coordinates" }), h("th", { scope: "col", text: "Reason" }))),
            h("tbody", {}, r.failures.map((p) => h("tr", {}, h("td", { text: String(p.index) }),
              h("td", { text: Object.entries(p.coords).map(([k, v]) => `${sym(k)} = ${fmt(v)}`).join(", ") }),
              h("td", { text: p.reason })))))));
      }
      if (r.definition && !defPre.textContent) defPre.textContent = toYaml(r.definition, 0).replace(/^\n/, "") + "\n";
    }

    async function act(what) {
      if (what === "delete" && !window.confirm(`Delete the study “${rec ? rec.name : id}”, its chunks and its results file? This cannot be undone.`)) return;
      actionsMsg.textContent = `${what}…`;
      try {
        if (what === "delete") {
          await getJSON(`studies/${id}`, { method: "DELETE" });
          announce(`Study ${rec ? rec.name : id} deleted.`);
          location.hash = "#/";
          return;
        }
        const r = await getJSON(`studies/${id}/${what}`, { method: "POST" });
        actionsMsg.textContent = what === "cancel" ? "Cancelled: finished chunks are kept; Resume continues from them." : "Queued again.";
        render(r);
        poll();
      } catch (e) {
        actionsMsg.textContent = `Could not ${what}: ${e.message}`;
      }
    }

    async function poll() {
      clearTimeout(timer);
      try {
        const r = await getJSON(`studies/${id}`);
        if (!alive(gen)) return;
        render(r);
        // Charts follow the finished points, at most every 5 s while the study runs.
        if (r.points_done > 0 && r.points_done !== charted && Date.now() - chartsAt > 5000) {
          charted = r.points_done;
          chartsAt = Date.now();
          if (!ctl) ctl = await setupResults(gen, id, results, () => rec);
          else ctl.redraw();
        }
        if (ACTIVE.includes(r.status) || charted !== r.points_done) {
          timer = setTimeout(poll, document.hidden ? POLL_MS * 5 : POLL_MS);
        }
      } catch (e) {
        if (!alive(gen)) return;
        if (e.status === 404) {
          live.textContent = "";
          results.remove();
          facts.replaceChildren();
          actionsMsg.textContent = `No such study: ${e.message}`;
          return;
        }
        live.textContent = `Could not load the study: ${e.message}`;
        timer = setTimeout(poll, POLL_MS * 3);
      }
    }

    const downloads = document.getElementById("downloads");
    function dlButton(label, path, name) {
      return h("button", { type: "button", text: label, onclick: () => download(typeof path === "function" ? path() : path, name, dlStatus) });
    }
    const sel = () => (ctl ? ctl.params() : {});
    downloads.append(
      dlButton("NetCDF dataset", `studies/${id}/dataset`, `${id}.nc`),
      dlButton("Slice as CSV", () => `studies/${id}/data${query(Object.assign({ format: "csv", nearest: "true", variable: ctl ? ctl.curveVariable() : "transmittance_db" }, sel()))}`, `${id}-slice.csv`),
      dlButton("Band edges CSV", () => `studies/${id}/bandgap${query(Object.assign({ format: "csv", nearest: "true" }, ctl ? ctl.mapParams() : {}))}`, `${id}-bands.csv`),
      ...["png", "svg"].flatMap((fmtx) => [
        dlButton(`Bandgap map ${fmtx.toUpperCase()}`, () => `studies/${id}/plots/bandgap.${fmtx}${query(Object.assign({ nearest: "true" }, ctl ? ctl.mapParams() : {}))}`, `${id}-bandgap.${fmtx}`),
        dlButton(`Transmittance ${fmtx.toUpperCase()}`, () => `studies/${id}/plots/transmittance.${fmtx}${query(Object.assign({ nearest: "true" }, ctl ? ctl.lineParams() : {}))}`, `${id}-transmittance.${fmtx}`),
        dlButton(`Effective mass ${fmtx.toUpperCase()}`, () => `studies/${id}/plots/effective-mass.${fmtx}${query(Object.assign({ nearest: "true" }, ctl ? ctl.massParams() : {}))}`, `${id}-effective-mass.${fmtx}`),
      ]));
    poll();
  }

  /** A 2-D slice (JSON of /data) as rows over y and columns over x, whatever its dim order. */
  function grid2d(slice, x, y) {
    const dims = slice.dims;
    const v = slice.values;
    if (dims.length === 0) return [[v]];
    if (dims.length === 1) return y && dims[0] === y ? v.map((a) => [a]) : [v];
    if (dims[0] === y && dims[1] === x) return v;
    if (dims[0] === x && dims[1] === y) return v[0].map((_, j) => v.map((row) => row[j]));
    throw new Error(`unexpected dimensions ${dims.join(", ")}`);
  }

  /**
   * The results panel: axis menus (x, y, and a value for every other varying axis), the map
   * and the curves. The axes' values are learned from the API itself: /bandgap names x, y and
   * the fixed axes; a 1-D slice of `failed` along each fixed axis gives its values.
   */
  async function setupResults(gen, id, section, current) {
    const note = section.querySelector("#results-note");
    note.textContent = "Loading the results…";
    let base;
    try {
      base = await getJSON(`studies/${id}/bandgap`);
    } catch (e) {
      note.textContent = `No map for this study: ${e.message}`;
      return null;
    }
    const axes = {};
    axes[base.x] = base.axes.x.values;
    if (base.y) axes[base.y] = base.axes.y.values;
    const others = Object.entries(base.slice || {}).filter(([, s]) => s.default).map(([k]) => k);
    const first = {};
    for (const k of others) first[k] = base.slice[k].value;
    for (const k of others) {
      const p = { variable: "failed", nearest: "true", [base.x]: axes[base.x][0] };
      if (base.y) p[base.y] = axes[base.y][0];
      for (const o of others) if (o !== k) p[o] = first[o];
      try {
        const s = await getJSON(`studies/${id}/data${query(p)}`);
        axes[k] = s.coords[k] || [first[k]];
      } catch (e) {
        axes[k] = [first[k]];
      }
    }
    if (!alive(gen)) return null;
    const names = Object.keys(axes);
    // SI axes are shown in prefixed units (gap in mm): their labels, values, legends and menus.
    const units = { [base.x]: base.axes.x.units };
    if (base.y) units[base.y] = base.axes.y.units;
    for (const k of others) units[k] = base.slice[k].units;
    const scale = Object.fromEntries(names.map((n) => [n, prefixed(units[n], axes[n])]));
    const si = (n) => Boolean(PREFIXES[units[n]]);
    const shown = (n, v) => (si(n) && typeof v === "number" ? v / scale[n][0] : v);
    const valueText = (n, v) => (si(n) && typeof v === "number" ? `${fmt(v / scale[n][0])} ${scale[n][1]}` : fmt(v));
    const rec = current;
    const state = { x: base.x, y: base.y, fixed: Object.assign({}, first), mapVar: "transmittance_db",
      curveVar: "transmittance_db", massVar: "theta_eff" };
    note.textContent = `Varying axes: ${names.map((n) => `${sym(n)} (${axes[n].length})`).join(", ")}. ` +
      "Irregular (×), irregular but possibly transient (◇: the impact-free response Γ_lin is admissible too, " +
      "so Γ there is not settled), unsettled (□) and failed (✖) points are marked; hatched cells are in a band.";

    const controls = h("form", { class: "toolbar", id: "axes", "aria-label": "Axes and slice", onsubmit: (e) => e.preventDefault() });
    const mapBox = h("div", { class: "chart", id: "map-chart" });
    const edgesList = h("ul", { id: "band-edges" });
    const curveBox = h("div", { class: "chart", id: "curve-chart" });
    const massBox = h("div", { class: "chart", id: "mass-chart" });
    const msg = h("p", { role: "status", class: "muted", id: "chart-message" });
    const varSelect = (id_, options, key) => {
      const s = h("select", { id: id_ }, Object.entries(options).map(([v, t]) => h("option", { value: v, text: t })));
      s.value = state[key];
      s.addEventListener("change", () => { state[key] = s.value; redraw(); });
      return s;
    };
    section.append(controls, msg,
      h("div", { class: "charts" },
        h("section", { class: "chart-panel", "aria-labelledby": "map-title" },
          h("div", { class: "panel-head" }, h("h3", { id: "map-title", text: "Bandgap map" }),
            h("label", { for: "map-variable", text: "Variable" }), varSelect("map-variable", MAP_VARIABLES, "mapVar")),
          mapBox, h("details", {}, h("summary", { text: "Band edges (text)" }), edgesList)),
        h("div", { class: "two-col" },
          h("section", { class: "chart-panel", "aria-labelledby": "curve-title" },
            h("div", { class: "panel-head" }, h("h3", { id: "curve-title", text: "Transmittance" }),
              h("label", { for: "curve-variable", text: "Variable" }), varSelect("curve-variable", CURVE_VARIABLES, "curveVar")),
            curveBox),
          h("section", { class: "chart-panel", "aria-labelledby": "mass-title" },
            h("div", { class: "panel-head" }, h("h3", { id: "mass-title", text: "Effective mass" }),
              h("label", { for: "mass-variable", text: "Variable" }), varSelect("mass-variable", MASS_VARIABLES, "massVar")),
            massBox))));
    // A chain study (docs/chains.md): Γ_j along the chain at one value of the x axis.
    const def = rec().definition || {};
    const chain = Boolean((def.model && def.model.cells > 1) || (def.grid && def.grid.cells !== undefined));
    const cellBox = h("div", { class: "chart", id: "cell-chart" });
    const cellAt = h("select", { id: "cell-at" });
    if (chain) {
      cellAt.addEventListener("change", () => { state.cellAt = cellAt.value; redraw(); });
      section.append(h("section", { class: "chart-panel", "aria-labelledby": "cell-title" },
        h("div", { class: "panel-head" }, h("h3", { id: "cell-title", text: "Along the chain" }),
          h("label", { for: "cell-at", id: "cell-at-label", text: "at" }), cellAt),
        cellBox,
        h("p", { class: "muted", text: "Γ_j at every cell j (proven points only: periodic and linear); Γ_j,lin of the chain without stops dashed." })));
    }

    function buildControls() {
      const fields = [];
      const opt = (n, chosen) => h("option", { value: n, text: sym(n), selected: n === chosen });
      const xSel = h("select", { id: "axis-x" }, names.map((n) => opt(n, state.x)));
      xSel.addEventListener("change", () => {
        const nx = xSel.value, ox = state.x;
        if (nx === state.y) state.y = ox; // x and y swap
        else { delete state.fixed[nx]; state.fixed[ox] = axes[ox][0]; }
        state.x = nx;
        buildControls();
        redraw();
      });
      fields.push(h("div", { class: "field" }, h("label", { for: "axis-x", text: "x axis" }), xSel));
      if (names.length > 1) {
        const ySel = h("select", { id: "axis-y" }, names.filter((n) => n !== state.x).map((n) => opt(n, state.y)));
        ySel.addEventListener("change", () => {
          const ny = ySel.value;
          if (state.y) state.fixed[state.y] = axes[state.y][0];
          delete state.fixed[ny];
          state.y = ny;
          buildControls();
          redraw();
        });
        fields.push(h("div", { class: "field" }, h("label", { for: "axis-y", text: "y axis (map rows, curve colours)" }), ySel));
      }
      for (const n of names) {
        if (n === state.x || n === state.y) continue;
        if (state.fixed[n] === undefined) state.fixed[n] = axes[n][0];
        const s = h("select", { id: `fixed-${n}` }, axes[n].map((v) => h("option", { value: String(v), text: valueText(n, v), selected: String(v) === String(state.fixed[n]) })));
        s.addEventListener("change", () => { state.fixed[n] = s.value; redraw(); });
        fields.push(h("div", { class: "field" }, h("label", { for: `fixed-${n}`, text: `${sym(n)} fixed at` }), s));
      }
      controls.replaceChildren(...fields);
    }

    const fixedParams = () => {
      const p = {};
      for (const [k, v] of Object.entries(state.fixed)) if (k !== state.x && k !== state.y && v !== undefined) p[k] = v;
      return p;
    };
    const label = (n) => (si(n) ? `${sym(n)} (${scale[n][1]})` : sym(n));

    /** How each point of the slice ended, -1 where it is not computed yet (a partial
     * dataset's `pending`; its `outcome` there is a placeholder, not a failure), TRANSIENT
     * where an irregular point may be transient. */
    async function outcomeGrid() {
      // only an adaptive study has `sampled` (asking another for it is an error, 422)
      const adaptive = Boolean((rec().definition || {}).adaptive);
      const [o, pending, sampled, transient] = await Promise.all([slice("outcome").catch(() => null),
        rec().status === "finished" ? null : slice("pending").catch(() => null),
        adaptive ? slice("sampled").catch(() => null) : null, slice("may_be_transient").catch(() => null)]);
      if (!o) return null;
      let grid = grid2d(o, state.x, state.y);
      if (transient) {
        const f = grid2d(transient, state.x, state.y);
        grid = grid.map((row, j) => row.map((v, i) => (v === 2 && f[j][i] ? TRANSIENT : v)));
      }
      if (pending) {
        const p = grid2d(pending, state.x, state.y);
        grid = grid.map((row, j) => row.map((v, i) => (p[j][i] ? -1 : v)));
      }
      if (sampled) { // an adaptive study: -2 where a line took no point (never drawn or marked)
        const t = grid2d(sampled, state.x, state.y);
        grid = grid.map((row, j) => row.map((v, i) => (t[j][i] ? v : -2)));
      }
      return grid;
    }

    async function drawMap(outcomes) {
      const p = Object.assign({ x: state.x, variable: state.mapVar, nearest: "true" }, fixedParams());
      if (state.y) p.y = state.y;
      const [m, outcome, reason, lasted] = await Promise.all([
        getJSON(`studies/${id}/bandgap${query(p)}`), outcomes, slice("reason").catch(() => null),
        slice("impacting_periods").catch(() => null),
      ]);
      const name = m.variable.name;
      const y = m.y || null;
      const z = m.dims.length === 1 ? [m[name]] : m[name];
      const att = m.dims.length === 1 ? [m.attenuating] : m.attenuating;
      C.heatmap(mapBox, {
        kind: "map", title: `${MAP_VARIABLES[name]} over ${label(m.x)}${y ? " × " + label(y) : ""}`,
        x: { label: label(m.x), values: m.axes.x.values.map((v) => shown(m.x, v)) },
        y: y ? { label: label(y), values: m.axes.y.values.map((v) => shown(y, v)) } : null,
        z, attenuating: att, threshold: m.threshold.value, zLabel: MAP_VARIABLES[name].replace(/, .*\(/, " ("),
        edges: (m.edges || []).map((e) => Object.assign({}, e, { y: y ? shown(y, e.y) : e.y,
          bands: e.bands.map((b) => b.map((v) => shown(m.x, v))) })), outcome, reason: reason ? withLasted(grid2d(reason, m.x, y), lasted, m.x, y) : null,
      });
      edgesList.replaceChildren(...(m.edges || []).map((e) => h("li", {
        text: `${y ? `${sym(y)} = ${valueText(y, e.y)}: ` : ""}${e.bands.length ? e.bands.map((b) => `${valueText(m.x, b[0])} – ${valueText(m.x, b[1])}`).join(", ") : "no band"}`,
      })), h("li", { class: "muted", text: m.threshold.meaning }));
    }

    /** Reasons with how long a may-be-transient point's impacting motion has lasted. */
    function withLasted(reasons, lasted, x, y) {
      if (!lasted) return reasons;
      const n = grid2d(lasted, x, y);
      return reasons.map((row, j) => row.map((r, i) => (n[j][i] === null || n[j][i] === undefined
        ? r : `${r}; impacts have lasted ${fmt(n[j][i])} periods`)));
    }

    async function slice(variable) {
      return getJSON(`studies/${id}/data${query(Object.assign({ variable, nearest: "true" }, fixedParams()))}`);
    }

    function seriesOf(s, o, extra) {
      const z = grid2d(s, state.x, state.y);
      const ys = state.y ? axes[state.y] : [null];
      return z.map((row, j) => Object.assign({
        label: state.y ? `${sym(state.y)} = ${valueText(state.y, ys[j])}${extra ? " " + extra : ""}` : (extra || s.variable),
        values: row, outcome: o ? o[j] : null,
        // an adaptive line's curve runs through its own samples, over the other lines' values
        bridge: o ? o[j].map((v) => v === -2) : null,
      }, extra ? { dashed: true, outcome: null } : {}));
    }

    async function drawCurves(outcomes) {
      const wantLin = state.curveVar === "transmittance_db";
      const [s, outcome, lin, mass] = await Promise.all([
        slice(state.curveVar), outcomes,
        wantLin ? slice("transmittance_linear_db").catch(() => null) : null,
        slice(state.massVar).catch((e) => e),
      ]);
      const series = seriesOf(s, outcome);
      if (lin) {
        seriesOf(lin, null, "(Γ_lin)").forEach((l, j) => { l.color = series[j].color = C_COLOR(j); series.push(l); });
      }
      C.lineChart(curveBox, { kind: "curves", title: `${CURVE_VARIABLES[state.curveVar]} over ${label(state.x)}`,
        x: { label: label(state.x), values: axes[state.x].map((v) => shown(state.x, v)) }, series, yLabel: Y_LABELS[state.curveVar],
        refLine: state.curveVar.endsWith("_db") ? (state.curveVar === "impact_effect_db" ? -1 : 0) : undefined });
      if (mass instanceof Error) {
        massBox.replaceChildren(h("p", { class: "muted", text: `No effective mass: ${mass.message}` }));
      } else {
        C.lineChart(massBox, { kind: "mass", title: `${MASS_VARIABLES[state.massVar]} over ${label(state.x)}`,
          x: { label: label(state.x), values: axes[state.x].map((v) => shown(state.x, v)) }, series: seriesOf(mass, outcome), yLabel: Y_LABELS[state.massVar], refLine: 0 });
      }
    }
    /** Γ_j over the cells of the chain at one value of the x axis (a chain study only). */
    async function drawCells(outcomes) {
      if (!chain) return;
      const xs = axes[state.x];
      if (state.cellAt === undefined || !xs.map(String).includes(String(state.cellAt))) state.cellAt = xs[Math.floor(xs.length / 2)];
      cellAt.replaceChildren(...xs.map((v) => h("option", { value: String(v), text: valueText(state.x, v), selected: String(v) === String(state.cellAt) })));
      document.getElementById("cell-at-label").textContent = `at ${sym(state.x)} =`;
      const p = Object.assign({ nearest: "true" }, fixedParams(), { [state.x]: state.cellAt });
      const [s, lin] = await Promise.all([
        getJSON(`studies/${id}/data${query(Object.assign({ variable: "cell_transmittance_db" }, p))}`),
        getJSON(`studies/${id}/data${query(Object.assign({ variable: "cell_transmittance_linear_db" }, p))}`),
        outcomes,
      ]);
      const ys = state.y ? axes[state.y] : [null];
      const rows = grid2d(s, "cell", state.y);
      const linRows = grid2d(lin, "cell", state.y);
      const series = [];
      rows.forEach((row, j) => {
        const name = state.y ? `${sym(state.y)} = ${valueText(state.y, ys[j])}` : "Γ_j";
        series.push({ label: name, values: row, color: C_COLOR(j) });
        series.push({ label: `${name} (Γ_j,lin)`, values: linRows[j], color: C_COLOR(j), dashed: true });
      });
      C.lineChart(cellBox, { kind: "cells", title: `Γ_j along the chain at ${sym(state.x)} = ${valueText(state.x, state.cellAt)}`,
        x: { label: "cell j", values: s.coords.cell }, series, yLabel: "Γ_j (dB)", refLine: 0 });
    }
    const PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22"];
    function C_COLOR(j) { return PALETTE[j % PALETTE.length]; }

    let drawing = null;
    async function redraw() {
      if (drawing) return drawing.then(redraw);
      msg.textContent = "Drawing…";
      const outcomes = outcomeGrid();
      const shown = current();
      drawing = Promise.all([drawMap(outcomes), drawCurves(outcomes), drawCells(outcomes)]).then(() => {
        msg.textContent = shown.status !== "finished"
          ? `Partial results: the ${shown.points_done.toLocaleString()} of ${shown.points_total.toLocaleString()} points finished when drawn (redrawn as more finish).` : "";
      }).catch((e) => { msg.textContent = `Could not draw: ${e.message}`; })
        .finally(() => { drawing = null; });
      return drawing;
    }

    buildControls();
    await redraw();
    return {
      redraw,
      params: fixedParams,
      curveVariable: () => state.curveVar,
      mapParams: () => Object.assign({ x: state.x, variable: state.mapVar }, state.y ? { y: state.y } : {}, fixedParams()),
      lineParams: () => Object.assign({ x: state.x }, state.y ? { hue: state.y } : {}, fixedParams()),
      massParams: () => Object.assign({ x: state.x }, fixedParams()),
    };
  }

  // ------------------------------------------------------------------ #/submit

  /** The line of a problem's path ("grid.gap") in YAML text, by indentation; 0 if unknown. */
  function lineOf(text, path) {
    const lines = text.split("\n");
    let from = 0, indent = -1, found = 0;
    for (const key of String(path).split(".")) {
      if (/^\d+$/.test(key) || key === "(root)" || key === "body") continue;
      let hit = -1;
      for (let i = from; i < lines.length; i++) {
        const m = /^(\s*)(?:-\s+)?["']?([^\s:"']+)["']?\s*:/.exec(lines[i]);
        if (!m) continue;
        const ind = m[1].length;
        if (found && ind <= indent) break;
        if (m[2] === key && ind > indent) { hit = i; indent = ind; break; }
      }
      if (hit < 0) return found;
      from = hit + 1;
      found = hit + 1;
    }
    return found;
  }

  function submitView() {
    const { gen } = page("Submit a study", "submit");
    const ta = h("textarea", { id: "study-text", spellcheck: "false", "aria-describedby": "problems-title study-help" });
    ta.value = sessionStorage.getItem("impactcell.draft") || EXAMPLE;
    const file = h("input", { id: "study-file", type: "file", accept: ".yaml,.yml,.json,application/yaml,application/json,text/yaml" });
    const resume = h("input", { id: "resume-flag", type: "checkbox" });
    const submitBtn = h("button", { type: "submit", class: "primary", id: "submit-study", text: "Submit study" });
    const problems = h("div", { id: "problems", class: "problems", "aria-live": "polite" },
      h("p", { class: "muted", text: "Problems of the study file are listed here, with their paths, after you submit." }));
    const form = h("form", { id: "submit-form", "aria-label": "Submit a study" },
      h("div", { class: "submit-grid" },
        h("div", {},
          h("label", { for: "study-text", text: "Study file (YAML or JSON)" }),
          h("p", { id: "study-help", class: "muted", text: "Paste a study definition, or upload a file. The format is that of the files in studies/ (docs/model.md)." }),
          ta,
          h("div", { class: "toolbar" },
            h("div", { class: "field" }, h("label", { for: "study-file", text: "Or upload a file" }), file),
            h("div", {}, resume, " ", h("label", { for: "resume-flag", text: "Run again if an identical study was cancelled or failed" }))),
          h("div", { class: "actions" }, submitBtn,
            h("button", { type: "button", text: "Insert the example", onclick: () => { ta.value = EXAMPLE; ta.focus(); } }))),
        h("aside", { "aria-labelledby": "problems-title" }, h("h2", { id: "problems-title", text: "Problems" }), problems)));
    view.append(form);
    ta.addEventListener("input", () => sessionStorage.setItem("impactcell.draft", ta.value));
    file.addEventListener("change", async () => {
      const f = file.files && file.files[0];
      if (!f) return;
      ta.value = await f.text();
      sessionStorage.setItem("impactcell.draft", ta.value);
      announce(`Loaded ${f.name} into the text box.`);
    });

    function showProblems(title, list) {
      ta.setAttribute("aria-invalid", "true");
      const items = list.map((p) => {
        const line = lineOf(ta.value, p.path);
        return h("li", {},
          h("span", { class: "path", text: p.path }), line ? " " : "",
          line ? h("button", { type: "button", class: "link", text: `(line ${line})`, "aria-label": `Go to line ${line} of the study file`, onclick: () => goto(line) }) : "",
          `: ${p.message}`);
      });
      problems.replaceChildren(h("p", { class: "error", role: "alert", text: title }), h("ul", { id: "problem-list" }, items));
    }
    function goto(line) {
      const lines = ta.value.split("\n");
      const start = lines.slice(0, line - 1).reduce((n, l) => n + l.length + 1, 0);
      ta.focus();
      ta.setSelectionRange(start, start + lines[line - 1].length);
    }

    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      const text = ta.value;
      const type = /^\s*[{[]/.test(text) ? "application/json" : "application/yaml";
      submitBtn.disabled = true;
      problems.replaceChildren(h("p", { class: "muted", text: "Submitting…" }));
      try {
        const r = await api(`studies${resume.checked ? "?resume=true" : ""}`, { method: "POST", headers: { "Content-Type": type }, body: text });
        if (!alive(gen)) return;
        if (r.ok) {
          const rec = await r.json();
          sessionStorage.removeItem("impactcell.draft");
          announce(r.status === 200 ? `An identical study exists: ${rec.name}.` : `Study ${rec.name} submitted.`);
          location.hash = `#/studies/${rec.id}`;
          return;
        }
        const e = await errorOf(r);
        if (e.problems && e.problems.length) showProblems(`The study was not accepted: ${e.problems.length} problem${e.problems.length > 1 ? "s" : ""}.`, e.problems);
        else showProblems("The study was not accepted.", [{ path: "(body)", message: e.message }]);
      } catch (e) {
        showProblems("The study could not be sent.", [{ path: "(network)", message: e.message }]);
      } finally {
        submitBtn.disabled = false;
      }
    });
  }

  // ------------------------------------------------------------------ #/regressions

  function regressionsView() {
    const { gen } = page("Nightly regressions", "regressions");
    const status = h("p", { class: "muted", "aria-live": "polite", text: "Loading the reports…" });
    const list = h("div", { id: "regressions" });
    view.append(h("p", { class: "muted", text: "Runs of the nightly regression suite, latest first. Open a run for its studies and the points that moved." }), status, list);
    getJSON("regressions?limit=100").then((data) => {
      if (!alive(gen)) return;
      status.textContent = data.total ? `${data.total} run${data.total > 1 ? "s" : ""}.` : "No nightly runs yet.";
      for (const run of data.items) {
        const verdict = run.ok === null ? "running" : run.ok ? "passed" : "failed";
        const body = h("div", {}, h("p", { class: "muted", text: "Loading…" }));
        const d = h("details", { class: "run", "data-id": String(run.id) },
          h("summary", {}, h("span", { class: `status ${run.ok === false ? "status-bad" : run.ok ? "status-ok" : "status-running"}`, text: verdict }),
            ` ${when(run.started_at)} · ${run.trigger} · ${run.summary || ""}`),
          body);
        d.addEventListener("toggle", () => { if (d.open && !d.dataset.loaded) { d.dataset.loaded = "1"; loadRun(run.id, body); } });
        list.append(d);
      }
    }).catch((e) => { if (alive(gen)) status.textContent = `Could not load the reports: ${e.message}`; });
  }

  async function loadRun(regId, body) {
    try {
      const run = await getJSON(`regressions/${regId}`);
      const rep = run.report || {};
      const out = [];
      if (run.error) out.push(h("p", { class: "error", text: run.error }));
      out.push(h("p", { text: `Started ${when(run.started_at)}, finished ${when(run.finished_at)}${rep.wall_s ? `, ${duration(rep.wall_s)}` : ""}${rep.mode ? `, mode ${rep.mode}` : ""}.` }));
      const studies = rep.studies || [];
      if (studies.length) {
        out.push(h("table", {}, h("caption", { class: "visually-hidden", text: "Studies of the run" }),
          h("thead", {}, h("tr", {}, ["Study", "Status", "Points", "Regressions", "Changes"].map((t) => h("th", { scope: "col", text: t })))),
          h("tbody", {}, studies.map((s) => h("tr", {},
            h("td", {}, s.study_id ? h("a", { href: `#/studies/${s.study_id}`, text: s.study }) : s.study),
            h("td", {}, badge(s.ok ? "finished" : "failed"), ` ${s.status}`),
            h("td", { class: "num", text: String(s.points) }), h("td", { class: "num", text: String(s.regressions) }),
            h("td", { class: "num", text: String((s.changes || []).length) }))))));
        const moved = studies.flatMap((s) => (s.changes || []).map((c) => Object.assign({ study: s.study }, c)));
        out.push(h("h3", { text: moved.length ? `Moved points (${moved.length})` : "No moved points" }));
        if (moved.length) {
          out.push(h("div", { class: "table-wrap" }, h("table", { class: "moved" },
            h("thead", {}, h("tr", {}, ["Study", "Coordinates", "Variable", "Kind", "Old", "New", "Change", "Tolerance"].map((t) => h("th", { scope: "col", text: t })))),
            h("tbody", {}, moved.slice(0, 200).map((c) => h("tr", { class: c.regression ? "regression" : "" },
              h("td", { text: c.study }),
              h("td", { text: Object.entries(c.coords || {}).map(([k, v]) => `${sym(k)} = ${fmt(v)}`).join(", ") }),
              h("td", { text: c.variable }), h("td", { text: c.kind }),
              h("td", { class: "num", text: fmt(c.old) }), h("td", { class: "num", text: fmt(c.new) }),
              h("td", { class: "num", text: c.kind === "outcome" ? "–" : fmt(c.delta) }),
              h("td", { text: typeof c.tolerance === "object" ? JSON.stringify(c.tolerance) : String(c.tolerance ?? "") })))))));
          if (moved.length > 200) out.push(h("p", { class: "muted", text: `The first 200 of ${moved.length} are shown; the markdown report has them all.` }));
        }
      }
      const st = h("p", { role: "status", class: "muted" });
      out.push(h("div", { class: "actions" }, h("button", { type: "button", text: "Markdown report", onclick: () => download(`regressions/${regId}?format=markdown`, `nightly-${regId}.md`, st) })), st);
      body.replaceChildren(...out);
    } catch (e) {
      body.replaceChildren(h("p", { class: "error", text: `Could not load the report: ${e.message}` }));
    }
  }

  // ------------------------------------------------------------------ router

  function route() {
    const hash = location.hash.replace(/^#\/?/, "");
    const parts = hash.split("/").filter(Boolean);
    if (parts[0] === "studies" && parts[1]) studyView(decodeURIComponent(parts[1]));
    else if (parts[0] === "submit") submitView();
    else if (parts[0] === "regressions") regressionsView();
    else homeView();
    view.querySelector("h1").focus();
  }

  // Escape would leave the page without data: the dialog stays until a token is given.
  document.getElementById("token-dialog").addEventListener("cancel", (ev) => ev.preventDefault());
  // The skip link moves the focus; following it would change the hash, i.e. the route.
  document.querySelector(".skip").addEventListener("click", (ev) => { ev.preventDefault(); view.focus(); });
  document.getElementById("forget-token").addEventListener("click", () => {
    sessionStorage.removeItem(TOKEN_KEY);
    document.getElementById("forget-token").hidden = true;
    announce("Token forgotten.");
    route();
  });
  document.getElementById("forget-token").hidden = !sessionStorage.getItem(TOKEN_KEY);
  window.addEventListener("hashchange", route);
  route();
})();
