// awl point-cloud viewer: WebGL 1, no library. Each <canvas class="awl-viewer"> names the
// <script type="text/plain"> elements holding its base64 Float32 positions (metres, centred) and
// Uint8 RGB colors. Drag rotates about the centre (z up), shift+drag pans, the wheel zooms,
// double-click resets. The status element reads "ok N points" once the first frame is drawn.
(function () {
  "use strict";

  function decode(id) {
    var el = document.getElementById(id);
    if (!el) throw new Error("viewer data element missing: " + id);
    var bin = atob(el.textContent.trim());
    var out = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out;
  }

  function perspective(fovy, aspect, near, far) {
    var f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
  }

  // Column-major 4x4 product a * b.
  function mul(a, b) {
    var o = new Array(16);
    for (var c = 0; c < 4; c++)
      for (var r = 0; r < 4; r++) {
        var s = 0;
        for (var k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
        o[c * 4 + r] = s;
      }
    return o;
  }

  function lookAt(eye, target, up) {
    var f = norm(sub(target, eye)), s = norm(cross(f, up)), u = cross(s, f);
    return [s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0,
      -dot(s, eye), -dot(u, eye), dot(f, eye), 1];
  }
  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function norm(a) { var l = Math.sqrt(dot(a, a)) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }

  function shader(gl, type, src) {
    var s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(s));
    return s;
  }

  var VS = "attribute vec3 p; attribute vec3 c; uniform mat4 mvp; uniform float ps; varying vec3 vc;" +
    "void main() { gl_Position = mvp * vec4(p, 1.0); gl_PointSize = ps; vc = c; }";
  var FS = "precision mediump float; varying vec3 vc; void main() { gl_FragColor = vec4(vc, 1.0); }";

  function start(canvas) {
    var status = document.getElementById(canvas.dataset.status);
    var count = parseInt(canvas.dataset.count, 10);
    var radius = parseFloat(canvas.dataset.radius) || 1;
    var gl = canvas.getContext("webgl", { preserveDrawingBuffer: true, antialias: false });
    if (!gl) { status.textContent = "no WebGL in this browser"; return; }
    var pos = new Float32Array(decode(canvas.dataset.pos).buffer);
    var col = decode(canvas.dataset.col);
    if (pos.length !== 3 * count || col.length !== 3 * count) throw new Error("viewer data length mismatch");
    var prog = gl.createProgram();
    gl.attachShader(prog, shader(gl, gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, shader(gl, gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("link: " + gl.getProgramInfoLog(prog));
    gl.useProgram(prog);
    function attribute(name, data, size, type, normalized) {
      var buf = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, buf);
      gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
      var loc = gl.getAttribLocation(prog, name);
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, size, type, normalized, 0, 0);
    }
    attribute("p", pos, 3, gl.FLOAT, false);
    attribute("c", col, 3, gl.UNSIGNED_BYTE, true);
    var uMvp = gl.getUniformLocation(prog, "mvp"), uPs = gl.getUniformLocation(prog, "ps");
    var size = document.getElementById(canvas.id + "-size");
    var home = { yaw: -Math.PI / 2 - 0.6, pitch: 0.45, dist: 2.6 * radius, target: [0, 0, 0] };
    var cam = Object.assign({}, home);
    var pending = false;

    function draw() {
      pending = false;
      gl.viewport(0, 0, canvas.width, canvas.height);
      gl.clearColor(0.118, 0.133, 0.157, 1);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      gl.enable(gl.DEPTH_TEST);
      var cp = Math.cos(cam.pitch);
      var eye = [cam.target[0] + cam.dist * cp * Math.cos(cam.yaw), cam.target[1] + cam.dist * cp * Math.sin(cam.yaw),
        cam.target[2] + cam.dist * Math.sin(cam.pitch)];
      var proj = perspective(0.8, canvas.width / canvas.height, cam.dist / 100, cam.dist + 4 * radius);
      gl.uniformMatrix4fv(uMvp, false, new Float32Array(mul(proj, lookAt(eye, cam.target, [0, 0, 1]))));
      gl.uniform1f(uPs, size ? parseFloat(size.value) : 2);
      gl.drawArrays(gl.POINTS, 0, count);
    }
    function redraw() { if (!pending) { pending = true; requestAnimationFrame(draw); } }

    var drag = null;
    canvas.addEventListener("mousedown", function (e) { drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey }; });
    window.addEventListener("mouseup", function () { drag = null; });
    window.addEventListener("mousemove", function (e) {
      if (!drag) return;
      var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
      drag.x = e.clientX; drag.y = e.clientY;
      if (drag.pan) {
        var k = cam.dist / canvas.clientHeight, s = Math.sin(cam.yaw), c = Math.cos(cam.yaw);
        cam.target = [cam.target[0] + k * dx * s, cam.target[1] - k * dx * c, cam.target[2] + k * dy];
      } else {
        cam.yaw -= dx * 0.01;
        cam.pitch = Math.max(-1.55, Math.min(1.55, cam.pitch + dy * 0.01));
      }
      redraw();
    });
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      cam.dist = Math.max(radius * 0.05, Math.min(radius * 20, cam.dist * Math.exp(e.deltaY * 0.001)));
      redraw();
    }, { passive: false });
    canvas.addEventListener("dblclick", function () { cam = Object.assign({}, home); redraw(); });
    if (size) size.addEventListener("input", redraw);
    draw();
    var err = gl.getError();
    if (err !== gl.NO_ERROR) throw new Error("WebGL error " + err);
    status.textContent = "ok " + count + " points";
  }

  var canvases = document.querySelectorAll("canvas.awl-viewer");
  for (var i = 0; i < canvases.length; i++) {
    try {
      start(canvases[i]);
    } catch (e) {
      var st = document.getElementById(canvases[i].dataset.status);
      if (st) st.textContent = "error: " + e.message;
      throw e;
    }
  }
})();
