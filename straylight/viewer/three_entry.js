// The parts of three.js the report's 3-D view uses (straylight/viewer/view3d.js), bundled into
// three-view.min.js as one script that defines the global THREE (see README.md in this folder).
export {
  WebGLRenderer, Scene, PerspectiveCamera, BufferGeometry, BufferAttribute, Mesh, MeshLambertMaterial,
  MeshBasicMaterial, LineSegments, LineBasicMaterial, Group, Color, Vector3, Box3, Sphere, AmbientLight,
  DirectionalLight, DoubleSide, RingGeometry, EdgesGeometry,
} from 'three';
export {OrbitControls} from 'three/examples/jsm/controls/OrbitControls.js';
