/* Interactive view of the site's 3D model (progressive enhancement of the static renders).
 * The model comes from model.glb.js (the GLB as base64, so that it loads from a file system, where
 * browsers refuse fetch); three.js and its GLTFLoader and OrbitControls are vendored beside it.
 * Without JavaScript or WebGL the static renders stay the only view. */
(function () {
  "use strict";
  var host = document.getElementById("model-viewer");
  if (!host || !window.THREE || !THREE.GLTFLoader || !THREE.OrbitControls || !window.cisternModelGlb) {
    return;
  }
  function bytesOf(base64) {
    var text = atob(base64), bytes = new Uint8Array(text.length);
    for (var i = 0; i < text.length; i++) { bytes[i] = text.charCodeAt(i); }
    return bytes.buffer;
  }
  var renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: true });
  } catch (error) {
    host.setAttribute("data-state", "no-webgl");
    return;
  }
  host.hidden = false;
  var width = host.clientWidth || 800, height = Math.round(width * 0.6);
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(width, height);
  renderer.setClearColor(0xffffff, 1);
  host.appendChild(renderer.domElement);
  var scene = new THREE.Scene();
  scene.add(new THREE.HemisphereLight(0xffffff, 0x444444, 0.9));
  var sun = new THREE.DirectionalLight(0xffffff, 0.6);
  sun.position.set(1, 2, 1.5);
  scene.add(sun);
  var camera = new THREE.PerspectiveCamera(45, width / height, 0.01, 1000);
  var controls = new THREE.OrbitControls(camera, renderer.domElement);
  controls.enableDamping = true;
  new THREE.GLTFLoader().parse(bytesOf(window.cisternModelGlb), "", function (gltf) {
    var model = gltf.scene, triangles = 0;
    model.traverse(function (node) {
      if (node.isMesh) {
        node.material.side = THREE.DoubleSide;
        node.material.vertexColors = true;
        triangles += node.geometry.index ? node.geometry.index.count / 3 : 0;
      }
    });
    scene.add(model);
    var box = new THREE.Box3().setFromObject(model), centre = box.getCenter(new THREE.Vector3());
    var size = box.getSize(new THREE.Vector3()).length();
    camera.position.set(centre.x + 0.6 * size, centre.y + 0.5 * size, centre.z + 0.6 * size);
    controls.target.copy(centre);
    controls.update();
    host.setAttribute("data-state", "loaded");
    host.setAttribute("data-triangles", String(triangles));
    (function frame() {
      controls.update();
      renderer.render(scene, camera);
      window.requestAnimationFrame(frame);
    })();
  }, function (error) {
    host.setAttribute("data-state", "error");
    host.hidden = true;
  });
})();
