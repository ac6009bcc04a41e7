// The label QA report's scene pages (dataset_tools.report): frame strip, pass selector and the
// BEV cell read-out. Plain JavaScript, no library; the page works from file:// (cells.js is a
// script, not fetched JSON, because browsers refuse fetch() from file:// pages).
(function () {
  "use strict";
  var R = window.REPORT;
  if (!R || !R.scene) return; // the overview needs no script
  var S = R.scene, cur = -1, pass = "rgb", decoded = {};
  var $ = function (id) { return document.getElementById(id); };

  function dir(f) { return "../frames/" + f.name + "/"; }
  function el(tag, attrs, text) {
    var e = document.createElement(tag);
    for (var k in attrs) e.setAttribute(k, attrs[k]);
    if (text !== undefined) e.textContent = text;
    return e;
  }
  function hasPass(f, p) {
    return f.cameras.some(function (c) { return !!f.images[c][p]; });
  }

  function showCameras() {
    var f = S.frames[cur], box = $("cameras");
    box.textContent = "";
    f.cameras.forEach(function (c) {
      var file = f.images[c][pass] || f.images[c].rgb;
      var fig = el("figure");
      fig.appendChild(el("img", { src: dir(f) + file, alt: c + " " + pass, "data-camera": c }));
      fig.appendChild(el("figcaption", {}, c + ": " + (f.images[c][pass] ? pass : "rgb (no " + pass + ")")));
      box.appendChild(fig);
    });
    Array.prototype.forEach.call(document.querySelectorAll("#passes button"), function (b) {
      b.classList.toggle("on", b.dataset.pass === pass);
      b.disabled = !hasPass(f, b.dataset.pass);
    });
  }

  function showBev() {
    var f = S.frames[cur], box = $("bev");
    box.textContent = "";
    S.bev.forEach(function (v) {
      var fig = el("figure"), wrap = el("div", { class: "bevbox" });
      var img = el("img", { src: dir(f) + f.bev[v[0]], alt: v[1], "data-view": v[0] });
      wrap.appendChild(img);
      wrap.appendChild(el("div", { class: "mark" }));
      wrap.addEventListener("mousemove", function (e) { readCell(img, e, false); });
      wrap.addEventListener("click", function (e) { readCell(img, e, true); });
      fig.appendChild(wrap);
      fig.appendChild(el("figcaption", {}, v[1]));
      box.appendChild(fig);
    });
  }

  function legend() {
    var box = $("legend");
    function row(title, names, colours) {
      var line = el("div", {}, title);
      names.forEach(function (n, i) {
        var c = colours[i % colours.length], sw = el("span", { class: "sw" });
        sw.style.background = "rgb(" + c.join(",") + ")";
        line.appendChild(sw);
        line.appendChild(document.createTextNode(n));
      });
      box.appendChild(line);
    }
    row("labels:", S.class_names, S.class_colours);
    row("camera footprints:", S.frames[0].cameras, S.camera_colours);
  }

  function fmt(o) {
    return Object.keys(o).map(function (k) {
      var v = o[k];
      if (typeof v === "number") v = Math.round(v * 100) / 100;
      else if (v && typeof v === "object") v = JSON.stringify(v).replace(/"/g, "").replace(/,/g, ", ");
      return k + ": " + v;
    }).join("\n");
  }

  function showMeta() {
    var f = S.frames[cur], m = f.meta, c = {};
    Object.keys(f.consistency).forEach(function (k) {
      c[k] = f.consistency[k] === null ? "-" : (100 * f.consistency[k]).toFixed(1) + "%";
    });
    var text = [
      "split: " + f.split + ", family: " + m.family + ", t = " + m.time_s + " s",
      "ego: " + fmt(m.ego_pose).replace(/\n/g, ", "),
      "weather:\n  " + fmt(m.weather).replace(/\n/g, "\n  "),
      "sun: " + fmt(m.sun).replace(/\n/g, ", "),
      "actors: " + m.actors + " (" + fmt(m.actors_by_kind).replace(/\n/g, ", ") + ")",
      "render s: " + fmt(m.timings).replace(/\n/g, ", "),
      "mean p(o): " + f.visibility_mean.toFixed(3) + ", cells p >= 0.5: " + (100 * f.visible_share).toFixed(1) + "%",
      "consistency: " + fmt(c).replace(/\n/g, ", ")
    ];
    var a = S.audit[f.name];
    text.push(a ? "audit: " + fmt(a).replace(/\n/g, ", ") : "audit: none");
    $("meta").textContent = text.join("\n");
  }

  function bytes(b64) {
    var s = atob(b64), a = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) a[i] = s.charCodeAt(i);
    return a;
  }

  function cells(name) {
    if (decoded[name]) return decoded[name];
    var c = R.cells[name];
    if (!c) return null;
    decoded[name] = { c: c, cls: bytes(c["class"]), p: bytes(c.p), h: bytes(c.height_dm), cams: bytes(c.cameras_seen) };
    return decoded[name];
  }

  function readCell(img, e, pin) {
    var f = S.frames[cur], d = cells(f.name);
    if (!d) { $("cell").textContent = "cell data not loaded"; return; }
    var r = img.getBoundingClientRect(), c = d.c;
    var col = Math.floor((e.clientX - r.left) / r.width * c.cols);
    var row = Math.floor((e.clientY - r.top) / r.height * c.rows);
    if (row < 0 || col < 0 || row >= c.rows || col >= c.cols) return;
    if (!pin && readCell.pinned === f.name) return;
    readCell.pinned = pin ? (readCell.pinned === f.name ? null : f.name) : readCell.pinned;
    var i = row * c.cols + col, seen = [];
    c.cameras.forEach(function (n, b) { if (d.cams[i] & (1 << b)) seen.push(n); });
    var x = c.x_max - (row + 0.5) * c.cell_m, y = c.y_max - (col + 0.5) * c.cell_m;
    $("cell").textContent = [
      "cell " + row + ", " + col + " (" + c.cell_m + " m): x " + x.toFixed(2) + " m, y " + y.toFixed(2) + " m",
      "class: " + (S.class_names[d.cls[i]] || d.cls[i]),
      "p(o): " + (d.p[i] / 250).toFixed(2),
      "height: " + (d.h[i] / 10).toFixed(1) + " m",
      "seen by: " + (seen.join(", ") || "no camera"),
      readCell.pinned ? "(pinned: click again to follow the mouse)" : ""
    ].join("\n");
    Array.prototype.forEach.call(document.querySelectorAll(".mark"), function (m) {
      var w = m.parentNode.getBoundingClientRect();
      m.style.display = "block";
      m.style.left = (col / c.cols * w.width) + "px";
      m.style.top = (row / c.rows * w.height) + "px";
      m.style.width = (w.width / c.cols) + "px";
      m.style.height = (w.height / c.rows) + "px";
    });
  }

  function loadCells(f) {
    if (R.cells[f.name]) return;
    var s = document.createElement("script");
    s.src = dir(f) + "cells.js";
    document.head.appendChild(s);
  }

  function show(i) {
    if (i < 0 || i >= S.frames.length) return;
    cur = i;
    var f = S.frames[i];
    readCell.pinned = null;
    $("frame-title").textContent = "frame " + f.frame + " (" + f.name + ")";
    Array.prototype.forEach.call(document.querySelectorAll("button.thumb"), function (b) {
      b.classList.toggle("on", +b.dataset.frame === i);
    });
    if (!hasPass(f, pass)) pass = "rgb";
    showCameras();
    showBev();
    showMeta();
    $("cell").textContent = "hover or click a BEV cell";
    loadCells(f);
    var hash = "#" + ("000000" + f.frame).slice(-6);
    if (location.hash !== hash) history.replaceState(null, "", hash);
  }

  function fromHash() {
    var n = parseInt(location.hash.slice(1), 10), i = 0;
    S.frames.forEach(function (f, k) { if (f.frame === n) i = k; });
    return i;
  }

  Array.prototype.forEach.call(document.querySelectorAll("button.thumb"), function (b) {
    b.addEventListener("click", function () { show(+b.dataset.frame); });
  });
  Array.prototype.forEach.call(document.querySelectorAll("#passes button"), function (b) {
    b.addEventListener("click", function () { pass = b.dataset.pass; showCameras(); });
  });
  document.addEventListener("keydown", function (e) {
    if (e.key === "ArrowRight") show(cur + 1);
    if (e.key === "ArrowLeft") show(cur - 1);
  });
  window.addEventListener("hashchange", function () { show(fromHash()); });
  legend();
  show(fromHash());
})();
