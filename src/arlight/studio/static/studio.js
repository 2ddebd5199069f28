// arlight studio page: shows the server's composites and sends the user's edits.
// Protocol: src/arlight/studio/protocol.py. No external libraries; works offline.
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("frame");
const ctx = canvas.getContext("2d");

// State the tests and the benchmark read (window.studio).
const studio = {
  info: null, header: null, frames: 0, errors: [], messages: [], latencies: [],
  selected: null, connected: false, ready: false, sendTimes: new Map(), seq: 0,
  send: null, shownLog: [], lastSent: null,
};
window.studio = studio;

let ws = null;
// The launch's token, from the page's URL (/?token=...): the WebSocket must give it too.
const token = new URLSearchParams(location.search).get("token") || "";
let dragging = false;
let frameTimes = [];
let drawing = false;
let pendingFrame = null;

function setStatus(text, isError) {
  const el = $("status");
  el.textContent = text || "";
  el.className = isError ? "error" : "";
}

function send(msg, track) {
  // track: a change that a frame will show; it gets a seq, echoed by that frame's header
  if (!ws || ws.readyState !== WebSocket.OPEN) return null;
  if (track) {
    studio.seq += 1;
    msg.seq = studio.seq;
    studio.sendTimes.set(msg.seq, {t: performance.now(), type: msg.type});
    studio.lastSent = {seq: msg.seq, t: studio.sendTimes.get(msg.seq).t};
  }
  ws.send(JSON.stringify(msg));
  return msg.seq;
}
studio.send = send;

function pixel(ev) {
  // pointer position in the studio camera's pixel coordinates
  const r = canvas.getBoundingClientRect();
  const w = studio.info ? studio.info.width : canvas.width;
  const h = studio.info ? studio.info.height : canvas.height;
  const x = Math.min(Math.max((ev.clientX - r.left) / r.width * w, 0), w);
  const y = Math.min(Math.max((ev.clientY - r.top) / r.height * h, 0), h);
  return {x, y};
}

function onInfo(info) {
  studio.info = info;
  $("scene-name").textContent = `${info.scene} · ${info.width}×${info.height}`;
  const sel = $("method");
  sel.innerHTML = "";
  for (const m of info.methods) {
    const opt = document.createElement("option");
    opt.value = m.name;
    opt.textContent = m.name + (m.progressive ? " (progressive)" : "");
    if (m.unsupported) { opt.disabled = true; opt.title = m.unsupported; }
    sel.appendChild(opt);
  }
  sel.value = info.method;
  describeMethod();
  const objSel = $("object");
  objSel.innerHTML = "";
  for (const name of Object.keys(info.objects)) {
    const opt = document.createElement("option");
    opt.value = opt.textContent = name;
    objSel.appendChild(opt);
  }
  studio.selected = objSel.value || null;
  const layers = $("layers");
  layers.innerHTML = "";
  for (const name of info.layers) {
    const label = document.createElement("label");
    label.innerHTML = `<input type="radio" name="layer" value="${name}"` +
      (name === "composite" ? " checked" : "") + `> ${name}`;
    layers.appendChild(label);
  }
  layers.querySelectorAll("input").forEach((el) =>
    el.addEventListener("change", () => send({type: "layer", name: el.value}, false)));
  studio.ready = true;
}

function describeMethod() {
  const m = studio.info.methods.find((x) => x.name === $("method").value);
  $("method-desc").textContent = m ? m.description : "";
  $("denoise").disabled = !(m && m.denoise);  // only the Monte Carlo methods have noise
}

function syncObjectControls() {
  const h = studio.header;
  const name = $("object").value;
  if (!h || !h.objects[name] || dragging) return;
  const p = h.objects[name];
  let yaw = p.yaw_deg > 180 ? p.yaw_deg - 360 : p.yaw_deg;
  if (document.activeElement !== $("yaw")) $("yaw").value = yaw;
  if (document.activeElement !== $("scale")) $("scale").value = Math.log2(p.scale);
  $("yaw-out").textContent = `${Math.round(yaw)}°`;
  $("scale-out").textContent = `${p.scale.toFixed(2)}×`;
}

async function onFrame(buf) {
  const view = new DataView(buf);
  const n = view.getUint32(0);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const blob = new Blob([new Uint8Array(buf, 4 + n)], {type: studio.info.format});
  pendingFrame = {header, blob};
  if (drawing) return;            // latest wins: only the newest frame gets decoded
  drawing = true;
  while (pendingFrame) {
    const {header: h, blob: b} = pendingFrame;
    pendingFrame = null;
    const bmp = await createImageBitmap(b);
    if (canvas.width !== bmp.width || canvas.height !== bmp.height) {
      canvas.width = bmp.width; canvas.height = bmp.height;
    }
    ctx.drawImage(bmp, 0, 0);
    bmp.close();
    shown(h);
  }
  drawing = false;
}

function shown(h) {
  const now = performance.now();
  if ($("status").textContent.startsWith("preparing")) setStatus("", false);
  studio.header = h;
  studio.frames += 1;
  studio.shownLog.push({at: now, seq: h.seq, factor: h.factor, refine: h.refine,
                       preview: !!h.preview});
  if (studio.shownLog.length > 256) studio.shownLog.shift();  // the benchmark reads it
  frameTimes.push(now);
  while (frameTimes.length && now - frameTimes[0] > 2000) frameTimes.shift();
  if (frameTimes.length > 1) {
    const fps = (frameTimes.length - 1) / ((now - frameTimes[0]) / 1000);
    $("fps").textContent = `${fps.toFixed(1)} fps`;
  }
  if (h.seq != null) {
    for (const [seq, sent] of studio.sendTimes) {
      if (seq <= h.seq) {
        if (seq === h.seq) {
          const ms = now - sent.t;
          studio.latencies.push({seq, ms, method: h.method, type: sent.type,
                                  render_s: h.stats.render_s, factor: h.factor,
                                  pose_s: h.stats.time_pose,
                                  server_ms: h.latency_ms, at: now, stats: h.stats});
          $("latency").textContent = `${ms.toFixed(0)} ms`;
        }
        studio.sendTimes.delete(seq);
      }
    }
  }
  // what this frame is: rendered size (upsampled to the canvas while dragging) and the
  // server's latency from the change it shows to the frame sent
  const size = h.width ? `${h.width}×${h.height}` : "";
  const scale = h.factor > 1 ? ` (1/${h.factor}, upsampled)` : "";
  const lat = h.latency_ms != null ? ` · ${h.latency_ms.toFixed(0)} ms` : "";
  $("overlay").textContent = size + scale + lat;
  const prog = h.refine > 0 ? `refining: ${h.refine} frame${h.refine > 1 ? "s" : ""}` : "";
  $("refine").textContent = prog + (h.rmse != null ? ` · RMSE ${h.rmse.toFixed(5)}` : "");
  const body = $("stages").querySelector("tbody");
  body.innerHTML = "";
  for (const [k, v] of Object.entries(h.stats)) {
    const tr = document.createElement("tr");
    tr.innerHTML = `<td>${k.replace(/^time_/, "")}</td><td>${(v * 1000).toFixed(1)} ms</td>`;
    body.appendChild(tr);
  }
  if ($("method").value !== h.method && document.activeElement !== $("method")) {
    $("method").value = h.method;
  }
  syncObjectControls();
}

function onJson(msg) {
  studio.messages.push(msg);
  if (msg.type === "info") onInfo(msg);
  else if (msg.type === "error") {
    studio.errors.push(msg);
    setStatus(`error: ${msg.message}`, true);
    if (msg.request === "save") {
      // files exist that this studio did not save: replace them only if the user says so
      // (the server never replaces an input of the scene, confirmed or not)
      const name = lastSave;
      lastSave = null;
      if (name && Array.isArray(msg.exists) && msg.exists.length &&
          confirm(`${msg.exists.join(", ")} already exist${msg.exists.length === 1 ? "s" : ""}` +
                  " and were not saved by this studio. Replace?")) {
        lastSave = name;
        send({type: "save", name, overwrite: true}, false);
      }
    }
  } else if (msg.type === "status") setStatus(msg.message, false);
  else if (msg.type === "picked") {
    if (msg.object) {
      studio.selected = msg.object;
      $("object").value = msg.object;
      dragging = true;
      canvas.classList.add("dragging");
    }
  } else if (msg.type === "saved") {
    lastSave = null;
    $("saved").textContent = `saved ${msg.scene} and ${msg.image} in ${msg.folder}`;
    setStatus(`saved ${msg.scene}`, false);
  }
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  ws = new WebSocket(`${proto}//${location.host}/ws?token=${encodeURIComponent(token)}`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => {
    studio.connected = true;
    $("conn").textContent = "connected"; $("conn").className = "pill ok";
  };
  ws.onclose = (ev) => {
    studio.connected = false;
    $("conn").textContent = "disconnected"; $("conn").className = "pill bad";
    if (!studio.ready) {  // refused before info: a wrong token, or too many tabs open
      setStatus("the studio refused this connection: open the URL with the token that " +
                "`arlight studio` printed, or close other studio tabs", true);
    }
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") onJson(JSON.parse(ev.data));
    else onFrame(ev.data);
  };
}

// ---------------------------------------------------------------- controls
canvas.addEventListener("pointerdown", (ev) => {
  const p = pixel(ev);
  canvas.setPointerCapture(ev.pointerId);
  send({type: "pick", x: p.x, y: p.y}, false);
});
canvas.addEventListener("pointermove", (ev) => {
  if (!dragging) return;
  const p = pixel(ev);
  send({type: "drag", x: p.x, y: p.y}, true);
});
const endDrag = () => {
  dragging = false;
  canvas.classList.remove("dragging");
  send({type: "release"}, false);   // progressive refinement may resume
};
canvas.addEventListener("pointerup", endDrag);
canvas.addEventListener("pointercancel", endDrag);
canvas.addEventListener("wheel", (ev) => {
  ev.preventDefault();
  const name = $("object").value;
  if (!name || !studio.header) return;
  const p = studio.header.objects[name];
  if (ev.shiftKey) {
    send({type: "pose", object: name, yaw_deg: p.yaw_deg + Math.sign(ev.deltaY) * 10}, true);
  } else {
    const s = Math.min(Math.max(p.scale * Math.pow(1.1, -Math.sign(ev.deltaY)), 0.05), 20);
    send({type: "pose", object: name, scale: s}, true);
  }
}, {passive: false});
$("method").addEventListener("change", () => {
  describeMethod();
  send({type: "method", name: $("method").value}, true);
});
$("object").addEventListener("change", () => { studio.selected = $("object").value; });
$("yaw").addEventListener("input", () => {
  $("yaw-out").textContent = `${$("yaw").value}°`;
  send({type: "pose", object: $("object").value, yaw_deg: Number($("yaw").value)}, true);
});
$("scale").addEventListener("input", () => {
  const s = Math.pow(2, Number($("scale").value));
  $("scale-out").textContent = `${s.toFixed(2)}×`;
  send({type: "pose", object: $("object").value, scale: s}, true);
});
$("exposure").addEventListener("input", () => {
  const ev = Number($("exposure").value);
  $("exposure-out").textContent = `${ev >= 0 ? "+" : ""}${ev.toFixed(1)} EV`;
  send({type: "exposure", ev}, false);
});
$("reset").addEventListener("click", () => send({type: "reset"}, true));
$("denoise").addEventListener("change", () =>
  send({type: "denoise", on: $("denoise").checked}, true));
let lastSave = null;  // the name of the save awaiting its reply (an overwrite asks first)
$("save").addEventListener("click", () => {
  lastSave = $("save-name").value;
  send({type: "save", name: lastSave}, false);
});

connect();
