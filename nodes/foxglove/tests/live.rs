//! dc-foxglove against live graphs started by `dc launch` (simulator + SPH + bridge), checked by an
//! independent WebSocket client (`client/`). Needs `dc`, `dc-sim` and `dc-sph` built beside the
//! bridge (`cargo build --workspace --bins`).

mod client;

use client::{Client, Grid, RawImage, SceneUpdate, FLOAT32};
use deep_contact::{bin, scratch_dir, unique_namespace};
use prost::Message as _;
use std::io::Read;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Balls in the scene.
const BALLS: usize = 60;
/// The SPH grid: rectangle 12 x 9 at spacing 0.25 -> ceil(extent / spacing) + 1 nodes per axis.
const GRID_BOUNDS: &str = "0,0,12,9";
const GRID_RES: f32 = 0.25;
const GRID_W: u32 = 49;
const GRID_H: u32 = 37;

/// The tests share two CPU cores: one graph at a time, so the steps/s comparison means something.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// A `dc launch` running in the background, its output collected.
struct Graph {
    child: Child,
    output: Arc<Mutex<String>>,
    readers: Vec<std::thread::JoinHandle<()>>,
}

impl Graph {
    /// Simulator (`steps` steps of `BALLS` balls), SPH grids and the bridge on `port`.
    fn start(test: &str, port: u16, steps: u32) -> Graph {
        let dir = scratch_dir(test);
        let file = dir.join("graph.toml");
        let toml = format!(
            r#"
[graph]
name = "foxglove-{test}"

[[nodes]]
name = "sph"
binary = "dc-sph"
daemon = true
params = {{ bounds = "{GRID_BOUNDS}", res = {GRID_RES} }}

[[nodes]]
name = "foxglove"
binary = "dc-foxglove"
daemon = true
params = {{ address = "127.0.0.1:{port}" }}

[[nodes]]
name = "sim"
binary = "dc-sim"
params = {{ seeds = "0", steps = {steps}, n = {BALLS}, model = "builtin" }}
"#
        );
        std::fs::write(&file, toml).unwrap();
        Graph::launch(&file, test, &dir)
    }

    /// `dc launch FILE` from folder `cwd`, in a namespace of its own, its output collected.
    fn launch(file: &std::path::Path, test: &str, cwd: &std::path::Path) -> Graph {
        let mut child = Command::new(bin("dc"))
            .current_dir(cwd)
            .arg("launch")
            .arg(file)
            .args(["--namespace", &unique_namespace(test)])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("run dc");
        let output = Arc::new(Mutex::new(String::new()));
        let mut readers = Vec::new();
        let pipes: Vec<Box<dyn Read + Send>> =
            vec![Box::new(child.stdout.take().unwrap()), Box::new(child.stderr.take().unwrap())];
        for mut pipe in pipes {
            let output = output.clone();
            readers.push(std::thread::spawn(move || {
                let mut buf = [0u8; 8192];
                while let Ok(n) = pipe.read(&mut buf) {
                    if n == 0 {
                        break;
                    }
                    output.lock().unwrap().push_str(&String::from_utf8_lossy(&buf[..n]));
                }
            }));
        }
        Graph { child, output, readers }
    }

    /// Waits for the graph to end (killing it after `limit`); its exit success and output.
    fn finish(mut self, limit: Duration) -> (bool, String) {
        let deadline = Instant::now() + limit;
        let status = loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                break s;
            }
            if Instant::now() > deadline {
                unsafe { libc::kill(self.child.id() as i32, libc::SIGINT) };
                break self.child.wait().unwrap();
            }
            std::thread::sleep(Duration::from_millis(50));
        };
        for r in self.readers.drain(..) {
            let _ = r.join();
        }
        let out = format!("status: {status}\n{}", self.output.lock().unwrap());
        (status.success(), out)
    }
}

/// Steps and seconds of the simulator's `simulation done` log lines.
fn sim_speed(output: &str) -> (u64, f64) {
    let (mut steps, mut secs) = (0u64, 0f64);
    for line in output.lines().filter(|l| l.contains("simulation done")) {
        for token in line.split_whitespace() {
            if let Some(v) = token.strip_prefix("steps=") {
                steps += v.parse::<u64>().unwrap_or(0);
            } else if let Some(v) = token.strip_prefix("secs=") {
                secs += v.parse::<f64>().unwrap_or(0.0);
            }
        }
    }
    (steps, secs)
}

/// What one client saw.
#[derive(Debug, Default)]
struct Seen {
    scenes: usize,
    circles: usize,
    walls: usize,
    grids: usize,
    heat_maps: usize,
    stats: usize,
}

/// Connects, checks serverInfo and the advertisements, subscribes to the scene, a grid, its heat
/// map and the solver statistics, and decodes until it has one of each.
async fn watch(port: u16, deadline: Instant) -> Seen {
    let mut c: Client = client::connect(port, deadline, None).await;
    assert!(c.wait_for_channels(&["/scene", "/stats/solve"], deadline).await, "no advertisement of /scene");
    let info = c.server_info.as_ref().expect("serverInfo comes first");
    assert!(info["name"].as_str().unwrap_or_default().starts_with("dc-foxglove"), "{info}");
    let scene = &c.channels["/scene"];
    assert_eq!((scene.encoding.as_str(), scene.schema_name.as_str()), ("protobuf", "foxglove.SceneUpdate"));
    let stats = &c.channels["/stats/solve"];
    assert_eq!((stats.encoding.as_str(), stats.schema_encoding.as_str()), ("json", "jsonschema"));
    c.subscribe("/scene").await;
    c.subscribe("/stats/solve").await;

    let mut seen = Seen::default();
    let mut grid_subscribed = false;
    while seen.scenes == 0 || seen.grids == 0 || seen.heat_maps == 0 || seen.stats == 0 {
        if !grid_subscribed && c.channels.contains_key("/grid/contacts") {
            let ad = &c.channels["/grid/contacts"];
            assert_eq!(ad.schema_name, "foxglove.Grid");
            c.subscribe("/grid/contacts").await;
            c.subscribe("/grid/contacts/heat/normal").await;
            grid_subscribed = true;
        }
        let Some(data) = c.next_data(deadline).await else {
            panic!("the stream ended or timed out; seen so far: {seen:?} (advertised: {:?})", c.channels.keys());
        };
        match data.topic.as_str() {
            "/scene" => {
                let update = SceneUpdate::decode(data.payload.as_slice()).expect("a SceneUpdate");
                let entity = |id: &str| {
                    update.entities.iter().find(|e| e.id == id).unwrap_or_else(|| panic!("no `{id}` entity"))
                };
                seen.circles = entity("balls").cylinders.len();
                seen.walls = entity("walls").cubes.len();
                assert!(update.entities.iter().all(|e| e.frame_id == "box"));
                seen.scenes += 1;
            }
            "/grid/contacts" => {
                let g = Grid::decode(data.payload.as_slice()).expect("a Grid");
                let names: Vec<&str> = g.fields.iter().map(|f| f.name.as_str()).collect();
                assert_eq!(names, ["normal", "tangent"]);
                assert!(g.fields.iter().all(|f| f.r#type == FLOAT32));
                assert_eq!(g.column_count, GRID_W);
                assert_eq!(g.cell_stride, 8);
                assert_eq!(g.row_stride, 8 * GRID_W);
                assert_eq!(g.data.len() as u32 / g.row_stride, GRID_H, "rows");
                assert_eq!(g.data.len() as u32 % g.row_stride, 0);
                seen.grids += 1;
            }
            "/grid/contacts/heat/normal" => {
                let img = RawImage::decode(data.payload.as_slice()).expect("a RawImage");
                assert_eq!((img.width, img.height, img.encoding.as_str()), (GRID_W, GRID_H, "rgb8"));
                assert_eq!(img.data.len() as u32, img.step * img.height);
                seen.heat_maps += 1;
            }
            "/stats/solve" => {
                let v: serde_json::Value = serde_json::from_slice(&data.payload).expect("JSON statistics");
                assert!(v["sweeps"].is_u64(), "{v}");
                seen.stats += 1;
            }
            other => panic!("data for `{other}`"),
        }
    }
    seen
}

fn assert_seen(seen: &Seen) {
    assert_eq!(seen.circles, BALLS, "one circle per ball: {seen:?}");
    assert!(seen.walls >= 1, "{seen:?}");
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap()
}

#[test]
fn independent_client_decodes_scene_and_grid_from_a_live_sim() {
    let _serial = serial();
    let port = free_port();
    let steps = 1500;
    let graph = Graph::start("client", port, steps);
    let seen = runtime().block_on(watch(port, Instant::now() + Duration::from_secs(60)));
    let (ok, out) = graph.finish(Duration::from_secs(180));
    assert!(ok, "{out}");
    assert_seen(&seen);
    assert_eq!(sim_speed(&out).0, steps as u64, "{out}");
    eprintln!("client saw {seen:?}");
}

#[test]
fn two_clients_at_once_both_get_the_scene_and_grid() {
    let _serial = serial();
    let port = free_port();
    let steps = 1500;
    let graph = Graph::start("two", port, steps);
    let deadline = Instant::now() + Duration::from_secs(60);
    let (a, b) = runtime().block_on(async { tokio::join!(watch(port, deadline), watch(port, deadline)) });
    let (ok, out) = graph.finish(Duration::from_secs(180));
    assert!(ok, "{out}");
    assert_seen(&a);
    assert_seen(&b);
    assert_eq!(sim_speed(&out).0, steps as u64, "{out}");
}

#[test]
fn client_that_never_reads_does_not_stall_the_sim() {
    let _serial = serial();
    let steps = 10_000;

    // Without any client.
    let port = free_port();
    let graph = Graph::start("alone", port, steps);
    let (ok, out) = graph.finish(Duration::from_secs(300));
    assert!(ok, "{out}");
    let (alone_steps, alone_secs) = sim_speed(&out);
    assert_eq!(alone_steps, steps as u64, "{out}");

    // With a client that subscribes to everything, then never reads again (a 4 KiB receive
    // buffer, so its socket is full within a few messages).
    let port = free_port();
    let graph = Graph::start("stuck", port, steps);
    let rt = runtime();
    let stuck = rt.block_on(async {
        let deadline = Instant::now() + Duration::from_secs(60);
        let mut c = client::connect(port, deadline, Some(4096)).await;
        let topics = ["/scene", "/stats/solve", "/grid/contacts", "/grid/bodies"];
        assert!(c.wait_for_channels(&topics, deadline).await, "advertised: {:?}", c.channels.keys());
        let all: Vec<String> = c.channels.keys().cloned().collect();
        for t in &all {
            c.subscribe(t).await;
        }
        c
    });
    let (ok, out) = graph.finish(Duration::from_secs(300));
    drop(stuck);
    assert!(ok, "{out}");
    let (stuck_steps, stuck_secs) = sim_speed(&out);
    assert_eq!(stuck_steps, steps as u64, "the simulator ran every step: {out}");
    let rate = |s: u64, t: f64| s as f64 / t.max(1e-9);
    let (alone, stuck) = (rate(alone_steps, alone_secs), rate(stuck_steps, stuck_secs));
    eprintln!(
        "sim steps/s: {alone:.0} without a client, {stuck:.0} with a client that never reads ({steps} steps, \
         {BALLS} balls, SPH grids, bridge at 30 Hz): ratio {:.2}",
        stuck / alone
    );
    // A wide bound, not a benchmark: a bridge that waited on the stuck socket would hold the
    // simulator to the client's pace (here: never), far below half its speed without the client.
    assert!(stuck >= 0.5 * alone, "the stuck client slowed the simulator: {stuck:.0} vs {alone:.0} steps/s:\n{out}");
}

/// The repository's own `launch/foxglove.toml`, as its README command starts it, twice at once
/// (two namespaces): both bridges start (each on a free port, which its log names), and an
/// independent client sees every channel of each (scene, frames, grids and heat maps, statistics,
/// control) and decodes a scene; the simulators are paced, so the graphs are still running.
#[test]
fn the_shipped_foxglove_graph_is_paced_and_two_start_at_once() {
    let _serial = serial();
    let file = deep_contact::repo_root().join("launch/foxglove.toml");
    // Each bridge's port, from its log line `serving Foxglove url=ws://127.0.0.1:PORT`.
    let start = |name: &str| {
        let graph = Graph::launch(&file, name, std::path::Path::new("/"));
        let deadline = Instant::now() + Duration::from_secs(60);
        let port = loop {
            let log = graph.output.lock().unwrap().clone();
            if let Some(at) = log.find("url=ws://127.0.0.1:") {
                let rest = &log[at + "url=ws://127.0.0.1:".len()..];
                break rest.split(|c: char| !c.is_ascii_digit()).next().unwrap().parse::<u16>().unwrap();
            }
            assert!(Instant::now() < deadline, "no URL logged: {log}");
            std::thread::sleep(Duration::from_millis(50));
        };
        (graph, port)
    };
    let (mut a, port_a) = start("foxglove-shipped-a");
    let (mut b, port_b) = start("foxglove-shipped-b");
    assert_ne!(port_a, port_b);
    let expected =
        ["/scene", "/tf", "/grid/contacts", "/grid/contacts/heat/normal", "/stats/solve", "/metrics/step", "/control"];
    for port in [port_a, port_b] {
        let deadline = Instant::now() + Duration::from_secs(60);
        runtime().block_on(async {
            let mut c: Client = client::connect(port, deadline, None).await;
            assert!(c.wait_for_channels(&expected, deadline).await, "advertised: {:?}", c.channels.keys());
            c.subscribe("/scene").await;
            loop {
                let data = c.next_data(deadline).await.expect("a scene before the deadline");
                if data.topic == "/scene" {
                    let update = SceneUpdate::decode(data.payload.as_slice()).expect("a SceneUpdate");
                    assert!(update.entities.iter().any(|e| e.id == "balls"));
                    break;
                }
            }
        });
    }
    for graph in [&mut a, &mut b] {
        assert!(graph.child.try_wait().unwrap().is_none(), "a paced graph is still running");
    }
    for graph in [a, b] {
        graph.finish(Duration::ZERO); // interrupted now: Ctrl-C
    }
}
