// probe.js — an optional buoy marker (PROTOCOL.md §7.4). Double-click
// the sea to drop a buoy there: it subscribes to a `probe` of that world point
// and bobs at the height the server reports every tick, so it should ride the
// rendered surface (which is drawn from the streamed, lossy grids). A one-shot
// `query` of the same point gives the exact height for comparison; the label
// shows both. Double-click the buoy's label (or press Escape) to remove it.
import * as THREE from 'three';

export class ProbeMarker {
  // opts: { scene, camera, canvas, send(obj) -> id }
  constructor({ scene, camera, canvas, send }) {
    this.camera = camera;
    this.canvas = canvas;
    this.send = send;
    this.point = null;          // [x, z] world metres, or null
    this.last = null;           // latest probe values { seq, simTime, height, normal, vv }
    this.exact = null;          // latest query_result point for `point`
    this.queryId = null;

    const buoy = new THREE.Group();
    const mat = new THREE.MeshBasicMaterial({ color: 0xff5a1f });
    const ball = new THREE.Mesh(new THREE.SphereGeometry(0.6, 16, 12), mat);
    const pole = new THREE.Mesh(new THREE.CylinderGeometry(0.06, 0.06, 2.4, 6), mat);
    pole.position.y = 1.2;
    buoy.add(ball, pole);
    buoy.visible = false;
    scene.add(buoy);
    this.buoy = buoy;

    const label = document.createElement('div');
    label.style.cssText = 'position:absolute;left:8px;bottom:8px;padding:4px 8px;font:12px monospace;' +
      'background:rgba(0,0,0,.55);color:#fff;border-radius:4px;display:none;cursor:pointer;z-index:5';
    label.title = 'double-click to remove the buoy';
    document.body.appendChild(label);
    this.label = label;

    canvas.addEventListener('dblclick', (ev) => this.drop(ev));
    label.addEventListener('dblclick', () => this.remove());
    window.addEventListener('keydown', (ev) => { if (ev.key === 'Escape') this.remove(); });

    const self = this; // read-only state for tests and curious users
    window.oceandProbe = Object.freeze({
      get point() { return self.point && [...self.point]; },
      get probe() { return self.last && { ...self.last }; },
      get exact() { return self.exact && { ...self.exact }; },
    });
  }

  // Screen position -> the point of the mean sea level (y = 0) under it.
  drop(ev) {
    const r = this.canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((ev.clientX - r.left) / r.width) * 2 - 1, -((ev.clientY - r.top) / r.height) * 2 + 1);
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const hit = new THREE.Vector3();
    if (!ray.ray.intersectPlane(new THREE.Plane(new THREE.Vector3(0, 1, 0), 0), hit)) return;
    this.place(hit.x, hit.z);
  }

  place(x, z) {
    this.point = [x, z];
    this.last = null;
    this.exact = null;
    this.subscribe();
  }

  remove() {
    if (!this.point) return;
    this.point = null;
    this.buoy.visible = false;
    this.label.style.display = 'none';
    this.send({ type: 'probe', points: [] });
  }

  // (Re)subscribe: after a drop and after a reconnect (hello).
  subscribe() {
    if (!this.point) return;
    this.send({ type: 'probe', points: [this.point] });
  }

  // Messages main.js does not handle itself. Returns true when it was ours.
  onMessage(msg) {
    if (msg.type === 'hello') { this.subscribe(); return false; }
    if (msg.type === 'probe_data' && this.point && msg.points.length === 1) {
      const [h, , , nx, ny, nz, vv] = msg.points[0];
      this.last = { seq: msg.seq, simTime: msg.sim_time, height: h, normal: [nx, ny, nz], vv };
      this.buoy.position.set(this.point[0], h, this.point[1]);
      this.buoy.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), new THREE.Vector3(nx, ny, nz).normalize());
      this.buoy.visible = true;
      // Once a second, ask for the exact value at this tick's time to compare.
      if (this.queryId === null && (!this.exact || msg.sim_time - this.exact.simTime > 1)) {
        this.queryTime = msg.sim_time;
        this.queryProbe = h;
        this.queryId = this.send({ type: 'query', points: [this.point], time: msg.sim_time });
      }
      this.draw();
      return true;
    }
    if (msg.type === 'query_result' && msg.id === this.queryId) {
      this.queryId = null;
      const p = msg.points[0];
      this.exact = { simTime: msg.sim_time, height: p.height, probeHeight: this.queryProbe };
      this.draw();
      return true;
    }
    if (msg.type === 'error' && msg.id === this.queryId) { this.queryId = null; return true; }
    return msg.type === 'probing' || msg.type === 'probe_data' || msg.type === 'query_result';
  }

  draw() {
    if (!this.point || !this.last) return;
    const [x, z] = this.point;
    let text = `buoy (${x.toFixed(1)}, ${z.toFixed(1)}) m: height ${this.last.height.toFixed(3)} m, ` +
      `heave ${this.last.vv.toFixed(2)} m/s`;
    if (this.exact) {
      const d = (this.exact.probeHeight - this.exact.height) * 1000;
      text += ` | exact query ${this.exact.height.toFixed(3)} m (probe − exact ${d.toFixed(1)} mm)`;
    }
    this.label.textContent = text;
    this.label.style.display = 'block';
  }
}
