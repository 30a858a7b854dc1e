// The parts of three.js the job page's 3D viewer uses, bundled by `npm run vendor`
// (esbuild, tree-shaken and minified) into services/api/static/vendor/three-viewer.min.js.
export {
  BufferGeometry,
  Color,
  Float32BufferAttribute,
  GridHelper,
  LineBasicMaterial,
  LineSegments,
  Mesh,
  MeshBasicMaterial,
  PerspectiveCamera,
  Points,
  PointsMaterial,
  Scene,
  SphereGeometry,
  Vector3,
  WebGLRenderer,
} from "three";
export { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
