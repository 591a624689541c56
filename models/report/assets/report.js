// Static report browser (models/report.py). Reads the JSON embedded in #report-data; no network.
(function () {
  "use strict";

  const data = JSON.parse(document.getElementById("report-data").textContent);
  const byName = new Map(data.materials.map(function (m) { return [m.name, m]; }));
  const state = { material: null, theta: null, hidden: new Set() };

  function $(id) { return document.getElementById(id); }

  function el(tag, attrs, children) {
    const node = document.createElement(tag);
    Object.entries(attrs || {}).forEach(function (kv) {
      if (kv[0] === "text") { node.textContent = kv[1]; } else { node.setAttribute(kv[0], kv[1]); }
    });
    (children || []).forEach(function (c) {
      node.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    });
    return node;
  }

  function fmt(x) { return (typeof x === "number" && isFinite(x)) ? x.toExponential(2) : "–"; }

  // A colour-bar or read-out number: 3 significant digits, plain between 0.01 and 1000.
  function num(x) {
    if (typeof x !== "number" || !isFinite(x)) { return "–"; }
    if (x === 0) { return "0"; }
    const a = Math.abs(x);
    return (a >= 0.01 && a < 1000) ? String(Number(x.toPrecision(3))) : x.toExponential(2);
  }

  function colour(model) { return (data.models[model] || {}).colour || "#000"; }

  function swatch(model) { return el("span", { "class": "swatch", style: "background:" + colour(model) }); }

  function materialsOf(cat) { return data.materials.filter(function (m) { return m.category === cat; }); }

  // The material of `cat` matching `want` best; the key just changed weighs most.
  function pickMaterial(cat, want, priorityKey) {
    let best = null, bestScore = -1;
    materialsOf(cat).forEach(function (m) {
      let score = 0;
      (data.selectors[cat] || []).forEach(function (s) {
        if (m.sel[s.key] === want[s.key]) { score += (s.key === priorityKey ? 1000 : 1); }
      });
      if (score > bestScore) { best = m; bestScore = score; }
    });
    return best;
  }

  function buildCategorySelect() {
    const sel = $("sel-category");
    sel.innerHTML = "";
    data.categories.forEach(function (c) {
      sel.appendChild(el("option", { value: c, text: c + " (" + materialsOf(c).length + ")" }));
    });
    sel.addEventListener("change", function () {
      const cur = state.material ? state.material.sel : {};
      setMaterial(pickMaterial(sel.value, cur, null));
    });
  }

  function buildParamSelects(m) {
    const box = $("param-selects");
    box.innerHTML = "";
    (data.selectors[m.category] || []).forEach(function (s) {
      const sel = el("select", { id: "sel-param-" + s.key, "data-param": s.key });
      s.values.forEach(function (v) { sel.appendChild(el("option", { value: v, text: v })); });
      sel.value = m.sel[s.key];
      sel.addEventListener("change", function () {
        const want = Object.assign({}, state.material.sel);
        want[s.key] = sel.value;
        setMaterial(pickMaterial(m.category, want, s.key));
      });
      box.appendChild(el("label", {}, [s.label + " ", sel]));
    });
  }

  function buildIncidentSelect(m) {
    const sel = $("sel-incident");
    sel.innerHTML = "";
    const incs = m.incidents || [];
    incs.forEach(function (inc, k) {
      sel.appendChild(el("option", { value: String(k), text: inc.theta + "°" + (inc.phi ? " (φ " + inc.phi + "°)" : "") }));
    });
    sel.disabled = incs.length === 0;
    if (incs.length) {
      let k = 0, d = Infinity;
      incs.forEach(function (inc, i) {
        const dd = state.theta === null ? i : Math.abs(inc.theta - state.theta);
        if (dd < d) { d = dd; k = i; }
      });
      sel.value = String(k);
    }
  }

  function buildModelChecks(m) {
    const box = $("model-checks");
    box.innerHTML = "";
    Object.keys(m.errors).forEach(function (name) {
      const cb = el("input", { type: "checkbox", id: "chk-model-" + name, "data-model": name });
      cb.checked = !state.hidden.has(name);
      cb.addEventListener("change", function () {
        if (cb.checked) { state.hidden.delete(name); } else { state.hidden.add(name); }
        render();
      });
      box.appendChild(el("label", { title: (data.models[name] || {}).description || "" }, [cb, swatch(name), name]));
    });
  }

  function currentIncident(m) {
    const incs = m.incidents || [];
    const k = parseInt($("sel-incident").value, 10);
    return incs.length ? incs[isNaN(k) ? 0 : Math.min(k, incs.length - 1)] : null;
  }

  function visibleModels(m) {
    return Object.keys(m.errors).filter(function (n) { return !state.hidden.has(n); });
  }

  function setImage(id, src) {
    const img = $(id);
    if (src) { img.setAttribute("src", src); img.style.display = ""; }
    else { img.removeAttribute("src"); img.style.display = "none"; }
  }

  function renderSpheres(m) {
    const box = $("spheres");
    if (!box) { return; }
    box.innerHTML = "";
    (m.spheres || []).forEach(function (s) {
      box.appendChild(el("figure", { "class": "wide", "data-angle": String(s.angle) }, [
        el("img", { src: s.src, alt: "lit spheres, light at " + s.angle + "°" }),
        el("figcaption", { text: "Light at " + s.angle + "° from the view. Reference: " + s.reference + "." })]));
    });
    if (m.spheres_note) { box.appendChild(el("p", { "class": "hint", text: m.spheres_note })); }
    (m.not_drawn || []).forEach(function (x) {
      box.appendChild(el("p", { "class": "hint not-drawn", text: x.figure + ": " + x.reason }));
    });
  }

  function renderFigures(m, inc) {
    renderSpheres(m);
    setImage("img-plane", inc ? inc.plane : null);
    setImage("img-orders", inc ? inc.orders : null);
    if (!inc) { renderOrdersLegend(null); }
    setImage("img-energy", m.energy || null);
    const box = $("topviews");
    box.innerHTML = "";
    if (!inc) {
      box.appendChild(el("p", { "class": "hint", text: "No figures were drawn for this material." }));
      return;
    }
    ["reference"].concat(visibleModels(m)).forEach(function (name) {
      const src = inc.top[name];
      if (!src) { return; }
      const third = name === "reference" ? "2σ noise" : "difference";
      const cap = el("figcaption", {}, [name === "reference" ? "" : swatch(name), name + " ",
        el("small", { text: "RGB · isovalues · " + third + " (±" + inc.diff_scale.toPrecision(2) + ")" })]);
      const img = el("img", { id: "img-top-" + name, "class": "hoverable", src: src,
        alt: name + " top view, θl = " + inc.theta + "°" });
      img.addEventListener("mousemove", function (ev) { showReadout(ev, img, m, inc); });
      img.addEventListener("mouseleave", hideReadout);
      box.appendChild(el("figure", { "data-model": name }, [cap, img, topLegend(inc, name)]));
    });
    renderOrdersLegend(inc);
    if (m.hover) { loadHover(m, function () { /* ready for the read-out */ }); }
  }

  // ------------------------------------------------------------------ colour bars
  // Drawn from the numbers of each incident (`legend`, `orders_legend`) and the panel colours
  // (`data.colours`) that the PNGs were drawn with; laid out under the disks of the composed image.

  function gridColumns(n, view) {
    const cols = [];
    for (let i = 0; i < n; i++) { if (i) { cols.push(view.gap_px + "fr"); } cols.push(view.disk_px + "fr"); }
    return cols.join(" ");
  }

  function bandBar(lg, label) {
    const strip = el("div", { "class": "cbar-strip" }, data.colours.bands.map(function (c) {
      return el("span", { style: "background:" + c });
    }));
    const e = lg.band_edges, mid = Math.floor(e.length / 2);
    return el("div", { "class": "cbar cbar-bands", "data-colorbar": "bands",
      title: "band edges, L in 1/sr: " + e.map(num).join(", ") + " (evenly spaced in log(1 + √L) up to " +
        num(lg.g_top) + "); white: above" }, [
      strip, el("div", { "class": "cbar-ticks" }, [el("span", { text: num(e[0]) }), el("span", { text: num(e[mid]) }),
        el("span", { text: num(e[e.length - 1]) })]),
      el("div", { "class": "cbar-label", text: label })]);
  }

  function divergingBar(lim, label) {
    const stops = data.colours.diverging;
    const strip = el("div", { "class": "cbar-strip", style: "background:linear-gradient(to right," + stops.join(",") + ")" });
    return el("div", { "class": "cbar cbar-diverging", "data-colorbar": "diverging" }, [
      strip, el("div", { "class": "cbar-ticks" }, [el("span", { text: "−" + num(lim) }), el("span", { text: "0" }),
        el("span", { text: "+" + num(lim) })]),
      el("div", { "class": "cbar-label", text: label })]);
  }

  function rgbNote(white, factor) {
    return el("div", { "class": "cbar cbar-rgb", "data-colorbar": "rgb" }, [el("div", { "class": "cbar-label",
      text: "RGB" + (factor && factor !== 1 ? " ×" + factor : "") + ": white at f ≥ " + num(white) + " 1/sr" })]);
  }

  function topLegend(inc, name) {
    const row = el("div", { "class": "legend-row", style: "grid-template-columns:" + gridColumns(3, data.views.top) });
    if (!inc.legend) { return row; }
    const a = rgbNote(inc.legend.rgb_white), b = bandBar(inc.legend, "luminance L, 1/sr"),
      c = divergingBar(inc.diff_scale, name === "reference" ? "2σ noise of log(1 + √L)" : "Δ log(1 + √L); red: brighter");
    a.style.gridColumn = "1"; b.style.gridColumn = "3"; c.style.gridColumn = "5";
    [a, b, c].forEach(function (x) { row.appendChild(x); });
    return row;
  }

  function renderOrdersLegend(inc) {
    const box = $("orders-legend");
    if (!box) { return; }
    box.innerHTML = "";
    const lgs = (inc && inc.orders_legend) || [];
    box.style.gridTemplateColumns = gridColumns(Math.max(lgs.length, 1), data.views.orders);
    lgs.forEach(function (lg, k) {
      const cell = el("div", { "class": "legend-cell" }, [
        el("div", { "class": "cbar-label", text: "order " + lg.order + (k === lgs.length - 1 ? "+" : "") +
          ": RGB" + (lg.factor !== 1 ? " ×" + lg.factor : "") + " white at f ≥ " + num(lg.rgb_white) + " 1/sr" }),
        bandBar(lg, "L, 1/sr")]);
      cell.style.gridColumn = String(2 * k + 1);
      box.appendChild(cell);
    });
  }

  // ------------------------------------------------------------------ hover read-out
  // hover.js of a material (models/report/hover.py) registers its coded values in
  // window.GONIO_HOVER; it is loaded by a <script> element, which works from file://.

  const hoverState = {};     // material name -> "loading" | "ready" | "failed"
  const hoverWaiting = {};   // material name -> callbacks
  const decoded = new Map(); // coded string -> Uint16Array
  const diskIndexBySize = {};
  let lastHover = null;

  function loadHover(m, done) {
    const reg = window.GONIO_HOVER || {};
    if (reg[m.name]) { hoverState[m.name] = "ready"; done(reg[m.name]); return; }
    if (hoverState[m.name] === "failed") { return; }
    (hoverWaiting[m.name] = hoverWaiting[m.name] || []).push(done);
    if (hoverState[m.name] === "loading") { return; }
    hoverState[m.name] = "loading";
    const s = document.createElement("script");
    s.src = m.hover;
    s.onload = function () {
      const h = (window.GONIO_HOVER || {})[m.name];
      hoverState[m.name] = h ? "ready" : "failed";
      (hoverWaiting[m.name] || []).splice(0).forEach(function (cb) { if (h) { cb(h); } });
      if (lastHover && lastHover.plane) { showPlaneReadout(lastHover.ev); }
      else if (lastHover) { showReadout(lastHover.ev, lastHover.img, lastHover.m, lastHover.inc); }
    };
    s.onerror = function () { hoverState[m.name] = "failed"; hoverWaiting[m.name] = []; };
    document.head.appendChild(s);
  }

  function codes(text) {
    let out = decoded.get(text);
    if (!out) {
      const bin = atob(text);
      out = new Uint16Array(bin.length >> 1);
      for (let i = 0; i < out.length; i++) { out[i] = bin.charCodeAt(2 * i) | (bin.charCodeAt(2 * i + 1) << 8); }
      decoded.set(text, out);
    }
    return out;
  }

  // Index of coarse pixel (r, c) among the stored pixels (inside the disk, row by row); -1 outside.
  function diskIndex(S) {
    if (!diskIndexBySize[S]) {
      const idx = new Int32Array(S * S).fill(-1);
      let n = 0;
      for (let r = 0; r < S; r++) {
        for (let c = 0; c < S; c++) {
          const a = 2 * c + 1 - S, b = 2 * r + 1 - S;
          if (a * a + b * b < S * S) { idx[r * S + c] = n++; }
        }
      }
      diskIndexBySize[S] = idx;
    }
    return diskIndexBySize[S];
  }

  // The value of a code (hover.py): null for "no value", strings for the out-of-range codes.
  function codeText(h, code) {
    if (code === h.codes.no_value) { return null; }
    if (code === h.codes.below) { return "< " + num(h.f_min); }
    if (code === h.codes.above) { return "> " + num(h.f_max); }
    if (code === h.codes.negative) { return "negative"; }
    return h.f_min * Math.exp((code - 1) * Math.log(h.f_max / h.f_min) / (h.n_codes - 1));
  }

  function hideReadout() {
    lastHover = null;
    const box = $("hover-readout");
    box.hidden = true;
    box.dataset.row = "";
  }

  function showReadout(ev, img, m, inc) {
    const view = data.views.top, S = data.views.hover_px;
    const rect = img.getBoundingClientRect();
    if (!img.naturalWidth || !rect.width) { return; }
    const px = (ev.clientX - rect.left) * img.naturalWidth / rect.width;
    const py = (ev.clientY - rect.top) * img.naturalHeight / rect.height;
    const pitch = view.disk_px + view.gap_px, panel = Math.floor(px / pitch), dx = px - panel * pitch;
    const c = Math.floor(dx * S / view.disk_px), r = Math.floor(py * S / view.disk_px);
    const x = (2 * c + 1) / S - 1, y = 1 - (2 * r + 1) / S;
    if (panel < 0 || panel >= view.panels || dx >= view.disk_px || r < 0 || r >= S || x * x + y * y >= 1) {
      hideReadout();
      return;
    }
    lastHover = { ev: ev, img: img, m: m, inc: inc };
    const theta = Math.acos(Math.sqrt(1 - x * x - y * y)) * 180 / Math.PI;
    const phi = ((Math.atan2(y, x) * 180 / Math.PI) + 360) % 360;
    const lines = [el("div", { "class": "ro-dir", text: "θv = " + theta.toFixed(1) + "°, φv = " + phi.toFixed(1) + "°" +
      (m.side === "btdf" ? " (below the surface)" : "") })];
    const h = (window.GONIO_HOVER || {})[m.name];
    const e = hoverEntry(m, inc, h, lines);
    if (e) { valueBlock(h, m, e, diskIndex(S)[r * S + c]).forEach(function (l) { lines.push(l); }); }
    placeReadout(ev, lines, { row: r, col: c, panel: panel, sample: "", part: "" });
  }

  // The material's hover entry of incident `inc`, or null with a line saying why.
  function hoverEntry(m, inc, h, lines) {
    if (!m.hover) { lines.push(el("div", { text: "no hover values in this report" })); return null; }
    if (!h) {
      lines.push(el("div", { text: hoverState[m.name] === "failed" ? "hover values missing (" + m.hover + ")" : "loading values…" }));
      loadHover(m, function () {});
      return null;
    }
    const e = h.incidents.filter(function (i) { return i.index === inc.index; })[0];
    if (!e) { lines.push(el("div", { text: "no hover values for this incident direction" })); return null; }
    return e;
  }

  // The reference ± its standard error and every shown model at stored sample k of `e`.
  function valueBlock(h, m, e, k) {
    const ref = codeText(h, codes(e.reference)[k]);
    if (ref === null) { return [el("div", { text: "masked cell: not compared" })]; }
    const se = codeText(h, codes(e.reference_se)[k]);
    const out = [el("div", { "class": "ro-ref" }, ["reference L = ", el("b", { text: num(ref) }), " ± " + num(se) + " 1/sr"])];
    const rows = visibleModels(m).filter(function (n) { return e.models[n]; }).map(function (n) {
      const v = codeText(h, codes(e.models[n])[k]);
      const q = (typeof v === "number" && typeof ref === "number" && ref > 0) ? v / ref : null;
      const rel = q === null ? "" : (q >= 10 || q <= 0.1) ? " (×" + num(q) + ")" :
        " (" + (q >= 1 ? "+" : "−") + num(Math.abs(100 * (q - 1))) + " %)";
      return el("tr", { "data-model": n }, [el("td", {}, [swatch(n), n]), el("td", { "class": "num", text: num(v) + rel })]);
    });
    if (rows.length) { out.push(el("table", { "class": "ro-models" }, rows)); }
    return out;
  }

  function placeReadout(ev, lines, marks) {
    const box = $("hover-readout");
    box.innerHTML = "";
    lines.forEach(function (l) { box.appendChild(l); });
    Object.entries(marks).forEach(function (kv) { box.dataset[kv[0]] = String(kv[1]); });
    box.hidden = false;
    const w = box.offsetWidth, hh = box.offsetHeight;
    box.style.left = Math.max(4, Math.min(ev.clientX + 16, window.innerWidth - w - 8)) + "px";
    box.style.top = Math.max(4, Math.min(ev.clientY + 16, window.innerHeight - hh - 8)) + "px";
  }

  // The plane-of-incidence figure: the plotted point nearest the pointer's abscissa.
  function showPlaneReadout(ev) {
    const m = state.material, inc = m ? currentIncident(m) : null, img = $("img-plane");
    const rect = img.getBoundingClientRect();
    if (!inc || !img.naturalWidth || !rect.width) { return; }
    const px = (ev.clientX - rect.left) * img.naturalWidth / rect.width;
    const py = (ev.clientY - rect.top) * img.naturalHeight / rect.height;
    const lines = [];
    const h = (window.GONIO_HOVER || {})[m.name];
    const e = hoverEntry(m, inc, h, lines);
    lastHover = { ev: ev, img: img, m: m, inc: inc, plane: true };
    if (!e) { placeReadout(ev, lines, { row: "", col: "", panel: "", sample: "", part: "" }); return; }
    const parts = e.plane || [];
    let p = -1;
    parts.forEach(function (q, i) {
      const b = q.box;
      if (px >= b[0] && px <= b[0] + b[2] && py >= b[1] && py <= b[1] + b[3]) { p = i; }
    });
    if (p < 0 || !parts[p].x.length) { hideReadout(); return; }
    const q = parts[p];
    const xd = q.xlim[0] + (px - q.box[0]) / q.box[2] * (q.xlim[1] - q.xlim[0]);
    let k = 0;
    q.x.forEach(function (x, i) { if (Math.abs(x - xd) < Math.abs(q.x[k] - xd)) { k = i; } });
    lines.push(el("div", { "class": "ro-dir", text: "signed θv = " + q.x[k].toFixed(1) + "° (" + q.label + ")" }));
    lines.push(el("div", { "class": "hint", text: "> 0 on the " + (m.side === "btdf" ? "straight-through" : "mirror") +
      " side: φv = " + num((inc.phi + (q.x[k] > 0 ? 180 : 0)) % 360) + "°" }));
    valueBlock(h, m, q, k).forEach(function (l) { lines.push(l); });
    placeReadout(ev, lines, { row: "", col: "", panel: "", sample: k, part: p });
  }

  function renderErrors(m) {
    const t = $("material-errors");
    t.innerHTML = "";
    const names = Object.keys(m.errors);
    const brdf = m.side === "brdf";
    const ncol = brdf ? 8 : 6;
    function th(text, title, attrs) { return el("th", Object.assign({ text: text, title: title }, attrs || {})); }
    const top = [th("model", "model (best first by the channel-mean RMSE)", { rowspan: "2" }),
      th(brdf ? "internal paths" : "BTDF", brdf ? "bounce order 1 dropped from the reference, the top lobe from the models"
        : "the whole BTDF", { colspan: "5" })];
    if (brdf) { top.push(th("total", "the whole BRDF", { colspan: "2" })); }
    const sub = [th("mean", "RMSE (eq. 4), mean over R, G, B"), th("R", "RMSE of the red channel"),
      th("G", "RMSE of the green channel"), th("B", "RMSE of the blue channel"), th("lum.", "RMSE of the luminance")];
    if (brdf) { sub.push(th("mean", "RMSE (eq. 4), mean over R, G, B"), th("lum.", "RMSE of the luminance")); }
    t.appendChild(el("thead", {}, [el("tr", {}, top), el("tr", {}, sub)]));
    const body = el("tbody");
    const ranked = names.slice().sort(function (a, b) {
      return m.errors[a].internal.rmse_mean - m.errors[b].internal.rmse_mean;
    });
    function cell(v, nf, main) {
      const td = el("td", { "class": "num" + (main ? " main" : ""), text: fmt(v) });
      if (typeof nf === "number" && v < 2 * nf) {
        td.classList.add("at-noise");
        td.title = "below twice the reference noise floor (" + fmt(nf) + ")";
      }
      return td;
    }
    ranked.forEach(function (name, r) {
      const e = m.errors[name], i = e.internal, tt = e.total;
      const tr = el("tr", { "data-model": name }, [el("td", {}, [swatch(name), name]),
        cell(i.rmse_mean, i.noise_floor_mean, true), cell(i.rmse[0], i.noise_floor[0]),
        cell(i.rmse[1], i.noise_floor[1]), cell(i.rmse[2], i.noise_floor[2]),
        cell(i.rmse_luminance, i.noise_floor_luminance)]);
      if (brdf) {
        tr.appendChild(cell(tt.rmse_mean, tt.noise_floor_mean));
        tr.appendChild(cell(tt.rmse_luminance, tt.noise_floor_luminance));
      }
      if (r === 0) { tr.classList.add("best"); }
      if (state.hidden.has(name)) { tr.classList.add("hidden-model"); }
      body.appendChild(tr);
    });
    if (names.length) {
      const i = m.errors[names[0]].internal, tt = m.errors[names[0]].total;
      const tr = el("tr", { "class": "noise" }, [el("td", { text: "noise floor" }),
        el("td", { "class": "num", text: fmt(i.noise_floor_mean) }), el("td", { "class": "num", text: fmt(i.noise_floor[0]) }),
        el("td", { "class": "num", text: fmt(i.noise_floor[1]) }), el("td", { "class": "num", text: fmt(i.noise_floor[2]) }),
        el("td", { "class": "num", text: fmt(i.noise_floor_luminance) })]);
      if (brdf) {
        tr.appendChild(el("td", { "class": "num", text: fmt(tt.noise_floor_mean) }));
        tr.appendChild(el("td", { "class": "num", text: fmt(tt.noise_floor_luminance) }));
      }
      body.appendChild(tr);
    } else {
      body.appendChild(el("tr", {}, [el("td", { colspan: String(ncol), text: "no model applies to this material" })]));
    }
    t.appendChild(body);
    const notes = $("material-notes");
    notes.innerHTML = "";
    const items = [];
    Object.entries(m.skipped || {}).forEach(function (kv) { items.push(el("li", { text: "not applicable — " + kv[0] + ": " + kv[1] })); });
    Object.entries(m.approximations || {}).forEach(function (kv) { items.push(el("li", { text: "approximation — " + kv[0] + ": " + kv[1] })); });
    Object.entries(m.failed || {}).forEach(function (kv) { items.push(el("li", { "class": "warn", text: "failed — " + kv[0] + ": " + kv[1] })); });
    if (items.length) { notes.appendChild(el("ul", { "class": "hint" }, items)); }
  }

  function renderInfo(m) {
    $("material-title").textContent = m.name + " (" + m.paper_name + ")";
    const params = Object.entries(m.params).map(function (kv) { return kv[0] + " = " + kv[1]; }).join(", ");
    $("material-info").textContent = params + " · " + m.side.toUpperCase() + " · " + m.parametrization + " slices " +
      m.resolution[0] + "×" + m.resolution[1] + " · " + Number(m.rays).toLocaleString("en") + " rays per slice";
  }

  function updateHash(m, inc) {
    try {
      const h = "#m=" + encodeURIComponent(m.name) + (inc ? "&t=" + inc.theta : "");
      history.replaceState(null, "", h);
    } catch (e) { /* some browsers refuse history on file://; the page works without it */ }
  }

  function render() {
    const m = state.material;
    if (!m) { return; }
    const inc = currentIncident(m);
    if (inc) { state.theta = inc.theta; }
    $("model-checks").querySelectorAll("input").forEach(function (cb) { cb.checked = !state.hidden.has(cb.dataset.model); });
    hideReadout();
    renderInfo(m);
    renderErrors(m);
    renderFigures(m, inc);
    document.body.dataset.material = m.name;
    document.body.dataset.incident = inc ? String(inc.index) : "";
    updateHash(m, inc);
  }

  function setMaterial(m) {
    if (!m) { return; }
    state.material = m;
    $("sel-category").value = m.category;
    buildParamSelects(m);
    buildIncidentSelect(m);
    buildModelChecks(m);
    render();
  }

  function fromHash() {
    const out = {};
    (location.hash || "").replace(/^#/, "").split("&").forEach(function (kv) {
      const i = kv.indexOf("=");
      if (i > 0) { out[kv.slice(0, i)] = decodeURIComponent(kv.slice(i + 1)); }
    });
    return out;
  }

  function init() {
    if (!data.materials.length) { return; }
    buildCategorySelect();
    $("sel-incident").addEventListener("change", render);
    $("img-plane").classList.add("hoverable");
    $("img-plane").addEventListener("mousemove", showPlaneReadout);
    $("img-plane").addEventListener("mouseleave", hideReadout);
    const h = fromHash();
    if (h.t !== undefined && !isNaN(parseFloat(h.t))) { state.theta = parseFloat(h.t); }
    setMaterial(byName.get(h.m) || data.materials[0]);
  }

  init();
})();
