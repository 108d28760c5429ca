"""The viewer's page: one HTML document with its style and script (no external files, so
it loads through an ssh tunnel or offline). The script sends key presses, mouse drags and
wheel steps and the menus' changes over the websocket ``/ws`` and shows what comes back
(``evaluation.view.server`` has the protocol)."""

PAGE = r"""<!doctype html>
<html><head><meta charset="utf-8"><title>whitted view</title>
<style>
 body { margin: 0; font: 13px/1.35 system-ui, sans-serif; background: #1e1e1e; color: #ddd;
        display: flex; }
 #main { flex: 1; padding: 8px; }
 #stage { position: relative; display: inline-block; background: #000; cursor: grab;
          user-select: none; }
 #frame { display: block; image-rendering: pixelated; }
 #overlay { position: absolute; left: 6px; top: 6px; background: rgba(0,0,0,.6);
            padding: 4px 6px; font: 12px monospace; white-space: pre-wrap; pointer-events: none;
            max-width: calc(100% - 24px); }
 #sbs-img { display: block; width: 100%; max-width: 1024px; image-rendering: pixelated; }
 #side { width: 300px; padding: 8px; background: #2a2a2a; min-height: 100vh; }
 #side label { display: block; margin: 4px 0; }
 #side select { width: 100%; }
 #status { font: 12px monospace; color: #fc6; margin-top: 6px; white-space: pre-wrap; }
 #verdict { font: 13px monospace; margin: 6px 0; white-space: pre-wrap; }
 .PASS { color: #6f6; } .WARN { color: #fc3; } .FAIL, .SIZE { color: #f66; }
 pre { background: #111; padding: 4px; font-size: 11px; }
 button { margin: 2px 0; }
</style></head>
<body>
<div id="main">
 <div id="stage" tabindex="0"><img id="frame" alt="frame" draggable="false">
  <div id="overlay">connecting...</div></div>
 <div id="sbs-panel" style="display:none">
  <div id="verdict"></div>
  <div style="font-size:11px">ours | Mitsuba | relative error (log, 1e-6 black .. 1e-1 white)</div>
  <img id="sbs-img" alt="side by side">
 </div>
 <div id="status"></div>
</div>
<div id="side">
 <b id="title">whitted view</b>
 <div style="font-size:11px">W/S/A/D/Q/E move, arrows turn; drag: orbit, right drag or
  Shift+drag: pan, wheel: zoom</div>
 <label>view <select id="preset"></select></label>
 <label>render mode <select id="mode"></select></label>
 <div id="effects"></div>
 <label>accelerator <select id="accel"></select></label>
 <label>triangle routine <select id="intersection"></select></label>
 <label>precision <select id="precision"></select></label>
 <label>spawn rule <select id="spawn"></select></label>
 <label>spp <select id="spp"></select></label>
 <label>shading <select id="shading"></select></label>
 <label><input type="checkbox" id="sbs"> Mitsuba side by side</label>
 <button id="save">save view (EXR + PNG)</button>
 <button id="viewtable">camera as [[views]] table</button>
 <pre id="table"></pre>
 <pre id="camera"></pre>
</div>
<script>
"use strict";
const $ = (id) => document.getElementById(id);
const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") +
                         location.host + "/ws");
const send = (m) => { if (ws.readyState === 1) ws.send(JSON.stringify(m)); };
let opts = null, filling = false;
function fill(id, items, value) {
  const sel = $(id); sel.innerHTML = "";
  for (const it of items) {
    const [v, label] = Array.isArray(it) ? it : [it, it];
    const o = document.createElement("option"); o.value = v; o.textContent = label;
    sel.appendChild(o);
  }
  if (value !== undefined && value !== null) sel.value = String(value);
}
function init(m) {
  opts = m; filling = true;
  $("title").textContent = "whitted view: " + m.scene + " (" + m.backend + ")";
  const v = m.values;
  if (!$("preset").options.length) fill("preset", m.presets, m.view);
  fill("mode", m.modes, v.mode); fill("accel", m.accels, v.accel);
  fill("intersection", m.routines, v.intersection); fill("precision", m.precisions, v.precision);
  fill("spawn", m.spawns, v.spawn); fill("spp", m.spps, v.spp);
  fill("shading", m.shadings, v.shading);
  const fx = $("effects"); fx.innerHTML = "effects:";
  for (const name of m.effects) {
    const l = document.createElement("label"), c = document.createElement("input");
    c.type = "checkbox"; c.id = "fx-" + name; c.checked = !v.effects_off.includes(name);
    c.onchange = () => send({t: "effect", name: name, on: c.checked});
    l.appendChild(c); l.appendChild(document.createTextNode(" " + name)); fx.appendChild(l);
  }
  filling = false;
}
for (const id of ["mode", "accel", "intersection", "precision", "spawn", "spp", "shading"]) {
  $(id).onchange = () => { if (!filling) send({t: "set", name: id, value: $(id).value}); };
}
$("preset").onchange = () => send({t: "preset", name: $("preset").value});
$("save").onclick = () => send({t: "save"});
$("viewtable").onclick = () => send({t: "viewtable", name: "viewer"});
$("sbs").onchange = () => {
  $("sbs-panel").style.display = $("sbs").checked ? "block" : "none";
  if ($("sbs").checked) $("verdict").textContent = "rendering with Mitsuba...";
  send({t: "sbs", on: $("sbs").checked});
};
function status(text) {
  const s = $("status");
  s.textContent = (text + "\n" + s.textContent).split("\n").slice(0, 8).join("\n");
}
const fmt = (x, d) => (x === null || x === undefined) ? "-" : x.toFixed(d);
ws.onmessage = (ev) => {
  const m = JSON.parse(ev.data);
  if (m.t === "init") init(m);
  else if (m.t === "frame") {
    const img = $("frame"), o = m.overlay;
    img.src = "data:image/jpeg;base64," + m.img;
    if (opts) img.style.width = opts.size[0] * Math.max(1, Math.floor(512 / opts.size[0])) + "px";
    img.dataset.seq = o.seq; img.dataset.width = o.size[0]; img.dataset.moving = o.moving;
    $("overlay").textContent =
      "frame " + fmt(o.frame_ms, 1) + " ms (render " + fmt(o.render_ms, 1) + ", encode " +
      fmt(o.encode_ms, 1) + ")  " + o.size[0] + "x" + o.size[1] + (o.moving ? " moving" : "") +
      (o.recorded ? " (recorded the kernels)" : "") +
      "\nmessage->sent " + fmt(o.latency_ms, 1) + " ms  " + (o.rays_per_s / 1e6).toFixed(2) +
      " Mrays/s\n" + o.effects;
    $("overlay").dataset.effects = o.effects;
    $("camera").textContent = JSON.stringify(m.camera);
  } else if (m.t === "msg") status(m.text);
  else if (m.t === "viewtable") {
    $("table").textContent = m.text; status("camera table: " + m.path);
  }
  else if (m.t === "sbs") {
    const v = $("verdict");
    if (m.error) {
      v.className = ""; v.textContent = m.error; $("sbs-img").removeAttribute("src"); return;
    }
    $("sbs-img").src = "data:image/jpeg;base64," + m.img;
    v.className = m.status; v.dataset.status = m.status;
    v.textContent = m.status + ": " + m.reason + "\nexcused " + m.excused + ", failing " +
      m.failing + " of " + m.pixels + " pixels; Mitsuba " + m.mitsuba_s.toFixed(2) + " s" +
      (m.note ? "\n" + m.note : "");
  }
};
ws.onclose = () => { $("overlay").textContent = "disconnected (the viewer stopped)"; };
const KEYS = new Set(["w", "s", "a", "d", "q", "e",
                      "arrowleft", "arrowright", "arrowup", "arrowdown"]);
document.addEventListener("keydown", (ev) => {
  const tag = ev.target.tagName;
  if (tag === "SELECT" || tag === "INPUT") return;
  const k = ev.key.toLowerCase();
  if (KEYS.has(k)) { send({t: "key", key: k}); ev.preventDefault(); }
});
const stage = $("stage");
let drag = null;
stage.addEventListener("contextmenu", (ev) => ev.preventDefault());
stage.addEventListener("mousedown", (ev) => {
  drag = {x: ev.clientX, y: ev.clientY, kind: (ev.button === 2 || ev.shiftKey) ? "pan" : "orbit"};
  stage.focus(); ev.preventDefault();
});
window.addEventListener("mouseup", () => { drag = null; });
window.addEventListener("mousemove", (ev) => {
  if (!drag) return;
  const img = $("frame");
  const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
  if (dx === 0 && dy === 0) return;
  drag.x = ev.clientX; drag.y = ev.clientY;
  // pan: screen pixels -> pixels of the still size; orbit: degrees per screen pixel
  const k = (drag.kind === "pan" && opts && img.clientWidth) ? opts.size[0] / img.clientWidth : 1;
  send({t: "drag", kind: drag.kind, dx: dx * k, dy: dy * k});
});
stage.addEventListener("wheel", (ev) => { send({t: "wheel", dy: ev.deltaY}); ev.preventDefault(); },
                       {passive: false});
</script>
</body></html>
"""
