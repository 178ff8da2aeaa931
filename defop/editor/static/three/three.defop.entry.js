// The three.js names the 3D page uses (defop_solid.js), bundled by esbuild into three.defop.min.js: see README.md.
export {
  BufferAttribute, BufferGeometry, Color, DirectionalLight, DynamicDrawUsage, HemisphereLight, Mesh,
  MeshLambertMaterial, MeshStandardMaterial, PerspectiveCamera, Plane, Raycaster, Scene, SphereGeometry, Vector2,
  Vector3, WebGLRenderer,
} from "three";
export { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
