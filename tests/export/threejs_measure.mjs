// Renders exported glTF materials in three.js (GLTFLoader + MeshPhysicalMaterial, WebGL 2) with one
// pixel per texel, at the camera and point light of `anisocap render` (docs/method.md section 4),
// and writes the linear float radiance of every texel into the page as base64.
//
// The page that loads this module holds an import map for "three" and "three/addons/", and a
// <script type="application/json" id="jobs"> block:
//   {"materials": [{"width": W, "height": H, "gltf": {...}}], "configurations":
//    [{"camera": [x, y, z], "light": [x, y, z], "intensity": [r, g, b]}]}
// Scene units as in anisocap: the material is the glTF quad (longest side 1) in z = 0, z up.
//
// Per-texel camera: the camera sits at the configuration's position, looks straight down (-z)
// and has an off-axis frustum whose image plane is parallel to the material, so the projection of
// the plane is affine and the W x H viewport's pixel centres fall exactly on the texel centres
// while every fragment still sees the camera at its own angle (three.js shades a perspective
// camera with the per-fragment view direction). The result is read back from a float render
// target (no tone mapping, no output colour conversion) and written as
//   <pre id="result">OK base64(Float32 RGBA, material-major, then configuration, rows top first)</pre>
// or <pre id="result">ERROR message</pre>.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";

function report(text) {
  const out = document.createElement("pre");
  out.id = "result";
  out.textContent = text;
  document.body.appendChild(out);
}

function base64(bytes) {
  let s = "";
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

async function main() {
  const jobs = JSON.parse(document.getElementById("jobs").textContent);
  const canvas = document.createElement("canvas");
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
  renderer.toneMapping = THREE.NoToneMapping;
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
  if (!renderer.extensions.has("EXT_color_buffer_float")) throw new Error("no float render targets (EXT_color_buffer_float)");
  const loader = new GLTFLoader();
  const chunks = [];
  let total = 0;
  for (const m of jobs.materials) {
    const gltf = await loader.parseAsync(JSON.stringify(m.gltf), "");
    const scene = new THREE.Scene();
    scene.add(gltf.scene);
    const light = new THREE.PointLight(0xffffff, 1, 0, 2);
    scene.add(light);
    const target = new THREE.WebGLRenderTarget(m.width, m.height, { type: THREE.FloatType, format: THREE.RGBAFormat, depthBuffer: true });
    const n = Math.max(m.width, m.height);
    const hx = m.width / (2 * n), hy = m.height / (2 * n);
    for (const c of jobs.configurations) {
      const [cx, cy, cz] = c.camera;
      const camera = new THREE.PerspectiveCamera();
      camera.position.set(cx, cy, cz);
      camera.quaternion.identity();
      camera.updateMatrixWorld(true);
      const near = 0.5 * cz, far = 2 * cz, k = near / cz;
      camera.projectionMatrix.makePerspective((-hx - cx) * k, (hx - cx) * k, (hy - cy) * k, (-hy - cy) * k, near, far);
      camera.projectionMatrixInverse.copy(camera.projectionMatrix).invert();
      const peak = Math.max(...c.intensity, 1e-30);
      light.color.setRGB(c.intensity[0] / peak, c.intensity[1] / peak, c.intensity[2] / peak, THREE.LinearSRGBColorSpace);
      light.intensity = peak;
      light.position.set(...c.light);
      renderer.setRenderTarget(target);
      renderer.setClearColor(0x000000, 0);
      renderer.clear();
      renderer.render(scene, camera);
      const pixels = new Float32Array(m.width * m.height * 4);
      renderer.readRenderTargetPixels(target, 0, 0, m.width, m.height, pixels);
      // WebGL rows run bottom to top; texel rows top to bottom.
      const rows = new Float32Array(pixels.length);
      for (let y = 0; y < m.height; ++y)
        rows.set(pixels.subarray((m.height - 1 - y) * m.width * 4, (m.height - y) * m.width * 4), y * m.width * 4);
      chunks.push(rows);
      total += rows.length;
    }
    target.dispose();
  }
  const all = new Float32Array(total);
  let offset = 0;
  for (const c of chunks) all.set(c, offset), (offset += c.length);
  report("OK " + base64(new Uint8Array(all.buffer)));
}

main().catch((e) => report("ERROR " + (e && e.stack ? e.stack : e)));
