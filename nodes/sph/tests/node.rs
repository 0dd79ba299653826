//! The real `dc-sph` binary on a private bus namespace: bodies and contacts in, grids out, clean
//! exit on a shutdown control message.

use msgs::{topics, Body, Contact, ControlKind, ControlMsg, Shape, StepHeader};
use runtime::{BusConfig, Node};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

#[test]
fn node_publishes_value_preserving_grids_for_each_step_and_exits_on_shutdown() {
    let namespace = format!("sph-test-{}", std::process::id());
    let bus = BusConfig { namespace: namespace.clone(), queue_depth: 16, ..Default::default() };
    let mut child = Command::new(env!("CARGO_BIN_EXE_dc-sph"))
        .args(["--bounds", "0,0,15,15", "--temporal"])
        .env("DC_BUS", serde_json::to_string(&bus).unwrap())
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .expect("start dc-sph");
    // Its ports exist once it logs that it is ready.
    let mut log = BufReader::new(child.stderr.take().unwrap()).lines();
    for line in log.by_ref() {
        if line.unwrap().contains("dc-sph ready") {
            break;
        }
    }
    std::thread::spawn(move || log.for_each(drop)); // keep draining its log

    let node = Node::new("sph-test", bus, false);
    let mut bodies = node.publisher(topics::BODIES).unwrap();
    let mut contacts = node.publisher(topics::CONTACTS).unwrap();
    let mut control = node.publisher(topics::CONTROL).unwrap();
    let mut grid_contacts = node.subscriber(topics::GRID_CONTACTS).unwrap();
    let mut grid_bodies = node.subscriber(topics::GRID_BODIES).unwrap();

    let ball = Body { id: 0, shape: Shape::Ball as u32, x: 4.0, y: 2.0, vx: 1.5, mass: 0.8, ..Default::default() };
    let contact = Contact {
        body_a: 0,
        body_b: 1,
        x: 10.3,
        y: 6.1,
        normal_impulse: 0.42,
        tangent_impulse: -0.07,
        ..Default::default()
    };
    // Publish steps until one comes back (the first may go out before the ports are connected).
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut step = 0;
    let grid = loop {
        assert!(Instant::now() < deadline, "no grid from dc-sph");
        let h = StepHeader { run_id: 7, simulation: 0, step };
        bodies.publish(&h, &[ball]).unwrap();
        contacts.publish(&h, &[contact]).unwrap();
        if let Some(r) = grid_contacts.recv_timeout(Duration::from_millis(300)).unwrap() {
            break r.into_frame();
        }
        step += 1;
    };
    let n = grid.header.channel("normal").unwrap();
    let t = grid.header.channel("tangent").unwrap();
    let sn = sph::sample_bilinear(&grid.header, grid.channel_data(n), contact.x, contact.y);
    let st = sph::sample_bilinear(&grid.header, grid.channel_data(t), contact.x, contact.y);
    assert!((sn - 0.42).abs() < 1e-5 && (st + 0.07).abs() < 1e-5, "{sn} {st}");
    assert_eq!((grid.header.width, grid.header.height), (121, 121));

    let bg = grid_bodies.recv_timeout(Duration::from_secs(5)).unwrap().expect("bodies grid").into_frame();
    assert_eq!(bg.header.step, grid.header.step);
    assert_eq!(bg.header.channels, 7);
    let vx = sph::sample_bilinear(&bg.header, bg.channel_data(0), ball.x, ball.y);
    let prev_normal = bg.header.channel("prev_normal").unwrap();
    assert!((vx - 1.5).abs() < 1e-5, "{vx}");
    assert!((sph::sample_bilinear(&bg.header, bg.channel_data(prev_normal), contact.x, contact.y) - 0.42).abs() < 1e-5);

    let shutdown = ControlMsg::simple(StepHeader::default(), ControlKind::Shutdown, 0);
    let stop = Instant::now() + Duration::from_secs(10);
    loop {
        control.publish_frame(&shutdown).unwrap();
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "dc-sph exited with {status}");
            break;
        }
        assert!(Instant::now() < stop, "dc-sph did not stop");
        std::thread::sleep(Duration::from_millis(100));
    }
}
