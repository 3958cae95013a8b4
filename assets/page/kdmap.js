// The report page's behaviour (report.html, written by kdmap): the views' wipe slider, zoom
// and values under the pointer, and the 3D view's model. A classic script: the page is opened
// from file://, where module scripts and fetches of local files are refused.
(function () {
  "use strict";
  var data = {};        // view id -> Float32Array of 7 values per sample
  var waiting = {};     // view id -> figures waiting for their data

  function half(h) {
    var s = h & 0x8000 ? -1 : 1, e = (h >> 10) & 0x1f, f = h & 0x3ff;
    if (e === 0) return s * f * Math.pow(2, -24);
    if (e === 31) return f ? NaN : s * Infinity;
    return s * (1 + f / 1024) * Math.pow(2, e - 15);
  }

  // Called by report/views/<view>.js.
  window.kdmapViewData = function (id, b64) {
    var bin = atob(b64), n = bin.length >> 1, v = new Float32Array(n);
    for (var i = 0; i < n; i++) {
      v[i] = half(bin.charCodeAt(2 * i) | (bin.charCodeAt(2 * i + 1) << 8));
    }
    data[id] = v;
    (waiting[id] || []).forEach(function (f) { f.querySelector(".readout").textContent = "point at the images for values"; });
  };

  function load(fig) {
    var id = fig.dataset.view;
    if (data[id] || waiting[id]) return;
    waiting[id] = [fig];
    var s = document.createElement("script");
    s.src = "report/views/" + encodeURIComponent(id) + ".js";
    s.onerror = function () { fig.querySelector(".readout").textContent = "no value data for this view"; };
    document.body.appendChild(s);
  }

  function fmt(v) {
    if (!isFinite(v)) return "-";
    var a = Math.abs(v);
    return a !== 0 && (a < 1e-3 || a >= 1e5) ? v.toExponential(3) : v.toPrecision(4);
  }

  function readout(fig, img, ev) {
    var id = fig.dataset.view, v = data[id];
    if (!v) { load(fig); return; }
    var w = +fig.dataset.w, h = +fig.dataset.h, st = +fig.dataset.stride;
    var r = img.getBoundingClientRect();
    var x = Math.floor((ev.clientX - r.left) / r.width * w), y = Math.floor((ev.clientY - r.top) / r.height * h);
    if (x < 0 || y < 0 || x >= w || y >= h) return;
    var cols = Math.ceil(w / st), k = 7 * (Math.floor(y / st) * cols + Math.floor(x / st));
    var p = [v[k], v[k + 1], v[k + 2]].map(fmt).join(", "), q = [v[k + 3], v[k + 4], v[k + 5]].map(fmt).join(", ");
    var e = isNaN(v[k + 6]) ? "-" : (100 * v[k + 6]).toFixed(2) + "%";
    fig.querySelector(".readout").textContent =
      "pixel (" + x + ", " + y + "): photo RGB [" + p + "], re-render RGB [" + q + "] (scene radiance units); relative error " + e;
  }

  function setupView(fig) {
    var wipe = fig.querySelector(".wipe");
    var apply = function () { fig.style.setProperty("--wipe", wipe.value + "%"); };
    wipe.addEventListener("input", apply);
    apply();
    fig.querySelectorAll("button[data-zoom]").forEach(function (b) {
      b.addEventListener("click", function () {
        var z = +b.dataset.zoom;
        fig.classList.toggle("zoomed", z > 1);
        fig.querySelectorAll(".stack").forEach(function (s) { s.style.width = z > 1 ? (z * +fig.dataset.w) + "px" : ""; });
      });
    });
    fig.querySelectorAll(".stack img").forEach(function (img) {
      img.addEventListener("mouseenter", function () { load(fig); });
      img.addEventListener("mousemove", function (ev) { readout(fig, img, ev); });
    });
  }

  function script(src, done) {
    var s = document.createElement("script");
    s.src = src;
    s.onload = done;
    document.body.appendChild(s);
  }

  // The viewer and the scene (megabytes on a large scene) load only when the 3D view is
  // scrolled near, so the rest of the page opens at once.
  function setupViewer() {
    var mv = document.getElementById("viewer3d");
    if (!mv) return;
    var started = false;
    var start = function () {
      if (started) return;
      started = true;
      script("report/model-viewer-umd.min.js", function () {
        script("report/scene_glb.js", function () {
          mv.src = "data:model/gltf-binary;base64," + window.KDMAP_GLB;
        });
      });
    };
    if (!("IntersectionObserver" in window)) return start();
    new IntersectionObserver(function (es) {
      if (es.some(function (e) { return e.isIntersecting; })) start();
    }, { rootMargin: "400px" }).observe(mv);
  }

  document.querySelectorAll("figure.view").forEach(setupView);
  setupViewer();
})();
