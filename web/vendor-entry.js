// The front-end libraries the app uses, bundled into one ES module by build-vendor.sh.
export * from "three";
export { OrbitControls } from "three/examples/jsm/controls/OrbitControls.js";
