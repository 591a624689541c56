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
  }

  function renderFigures(m, inc) {
    renderSpheres(m);
    setImage("img-plane", inc ? inc.plane : null);
    setImage("img-orders", inc ? inc.orders : null);
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
      box.appendChild(el("figure", { "data-model": name }, [
        el("img", { id: "img-top-" + name, src: src, alt: name + " top view, θl = " + inc.theta + "°" }), cap]));
    });
  }

  function renderErrors(m) {
    const t = $("material-errors");
    t.innerHTML = "";
    const names = Object.keys(m.errors);
    const brdf = m.side === "brdf";
    const head = ["model", brdf ? "internal" : "BTDF", "R", "G", "B", "luminance"].concat(brdf ? ["total", "total lum."] : []);
    t.appendChild(el("thead", {}, [el("tr", {}, head.map(function (h) { return el("th", { text: h }); }))]));
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
      body.appendChild(el("tr", {}, [el("td", { colspan: String(head.length), text: "no model applies to this material" })]));
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
    const h = fromHash();
    if (h.t !== undefined && !isNaN(parseFloat(h.t))) { state.theta = parseFloat(h.t); }
    setMaterial(byName.get(h.m) || data.materials[0]);
  }

  init();
})();
