// 3D view of a measured foot: the mesh (GLB, mm) and its 18 joints with the bones between them (three.js).
// Renders on demand (after loading, when the view moves, on resize), not in a loop.

import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

const SKIN = 0xd9a98a;
const JOINT = 0x0b5cad;
const BONE = 0x123a63;

function loadMesh(url) {
  return new Promise((resolve, reject) => new GLTFLoader().load(url, resolve, undefined, reject));
}

// Where to look from. A foot far from the origin is in the camera frame (OpenCV: y down, the camera at the
// origin): look from near the camera, turned a little to the right and down so that the view starts like the
// photo but shows depth. Otherwise it is in the foot frame (z up, heel at the origin): look from the inner
// side, a little from the front and above.
function initialView(box) {
  const center = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3()).length();
  if (center.length() > 1.5 * size) {
    const back = center.clone().normalize().negate().add(new THREE.Vector3(0.45, 0.3, 0)).normalize();
    return { center, size, position: center.clone().addScaledVector(back, 1.7 * size), up: new THREE.Vector3(0, -1, 0) };
  }
  const offset = new THREE.Vector3(0.55, -1.2, 0.75).normalize().multiplyScalar(1.6 * size);
  return { center, size, position: center.clone().add(offset), up: new THREE.Vector3(0, 0, 1) };
}

function skeleton(joints, parents, radius) {
  const group = new THREE.Group();
  const ball = new THREE.SphereGeometry(radius, 16, 12);
  // transparent like the mesh, so that they are drawn after it (three.js draws opaque objects first), on top
  const material = new THREE.MeshBasicMaterial({ color: JOINT, depthTest: false, transparent: true });
  const points = [];
  joints.forEach((p, i) => {
    const mesh = new THREE.Mesh(ball, material);
    mesh.position.set(p[0], p[1], p[2]);
    mesh.renderOrder = 2;
    group.add(mesh);
    const parent = parents[i];
    if (parent >= 0 && parent < joints.length) points.push(new THREE.Vector3(...joints[parent]), new THREE.Vector3(...p));
  });
  if (points.length) {
    const lines = new THREE.LineSegments(
      new THREE.BufferGeometry().setFromPoints(points),
      new THREE.LineBasicMaterial({ color: BONE, depthTest: false, transparent: true }),
    );
    lines.renderOrder = 1;
    group.add(lines);
  }
  return group;
}

export async function showFoot(container, meshUrl, joints, parents) {
  const gltf = await loadMesh(meshUrl);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xeef0f2);
  const foot = gltf.scene;
  foot.traverse((obj) => {
    if (obj.isMesh) {
      if (!obj.geometry.attributes.normal) obj.geometry.computeVertexNormals();
      obj.material = new THREE.MeshStandardMaterial({
        color: SKIN, roughness: 0.8, metalness: 0.0, transparent: true, opacity: 0.7, side: THREE.DoubleSide,
      });
    }
  });
  scene.add(foot);
  const box = new THREE.Box3().setFromObject(foot);
  const view = initialView(box);
  if (Array.isArray(joints) && joints.length) scene.add(skeleton(joints, parents, view.size * 0.012));

  scene.add(new THREE.HemisphereLight(0xffffff, 0x8d8d8d, 2.2));
  const key = new THREE.DirectionalLight(0xffffff, 1.6);
  scene.add(key);

  const camera = new THREE.PerspectiveCamera(35, 4 / 3, view.size / 100, view.size * 20);
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
  const canvas = renderer.domElement;
  canvas.tabIndex = 0;
  canvas.setAttribute('role', 'img');
  canvas.setAttribute('aria-label', '3D view of the measured foot and its joints; use the arrow keys, + and − to move');
  container.replaceChildren(canvas);

  const controls = new OrbitControls(camera, canvas);
  controls.listenToKeyEvents(canvas);
  controls.keyPanSpeed = 20;

  const render = () => {
    key.position.copy(camera.position); // light from the viewer: the side one looks at is never dark
    renderer.render(scene, camera);
  };
  const reset = () => {
    camera.up.copy(view.up);
    camera.position.copy(view.position);
    controls.target.copy(view.center);
    camera.lookAt(view.center);
    controls.update();
    render();
  };
  const resize = () => {
    const w = Math.max(container.clientWidth, 1);
    const h = Math.max(container.clientHeight, 1);
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    render();
  };
  const zoomKeys = (e) => {
    const factor = { '+': 0.85, '=': 0.85, '-': 1.18, '_': 1.18 }[e.key];
    if (e.key === 'r' || e.key === 'R') reset();
    if (!factor) return;
    camera.position.sub(controls.target).multiplyScalar(factor).add(controls.target);
    controls.update();
    e.preventDefault();
  };
  controls.addEventListener('change', render);
  canvas.addEventListener('keydown', zoomKeys);
  const observer = new ResizeObserver(resize);
  observer.observe(container);
  reset();
  resize();

  return {
    reset,
    dispose() {
      observer.disconnect();
      controls.dispose();
      canvas.removeEventListener('keydown', zoomKeys);
      renderer.dispose();
      scene.traverse((obj) => {
        if (obj.geometry) obj.geometry.dispose();
        if (obj.material) obj.material.dispose();
      });
    },
  };
}
