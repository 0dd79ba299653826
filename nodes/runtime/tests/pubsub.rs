//! Publishers and subscribers within one process (the multi-process tests live in the
//! workspace's `tests/`): slices that grow, and the zenoh CBOR path.

use msgs::{topics, Contact, StepHeader};
use runtime::{BusConfig, Node, Transport};
use std::time::Duration;

fn bus(test: &str, transport: Transport) -> BusConfig {
    BusConfig {
        namespace: format!("rt{}-{test}", std::process::id()),
        default_transport: transport,
        queue_depth: 16,
        ..Default::default()
    }
}

fn contacts(n: usize, seed: u32) -> Vec<Contact> {
    (0..n)
        .map(|i| Contact { body_a: i as u32, body_b: seed, normal_impulse: i as f32 * 0.5, ..Default::default() })
        .collect()
}

fn round_trip(transport: Transport, test: &str, sizes: &[usize]) {
    let bus = bus(test, transport);
    // Two zenoh sessions: the receiver listens on a loopback port, the sender connects to it.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut receiver_bus = bus.clone();
    receiver_bus.zenoh.listen = vec![endpoint.clone()];
    let mut sender_bus = bus;
    sender_bus.zenoh.connect = vec![endpoint];
    let sender = Node::new("sender", sender_bus, false);
    let receiver = Node::new("receiver", receiver_bus, false);
    let mut sub = receiver.subscriber(topics::CONTACTS).unwrap();
    let mut publisher = sender.publisher(topics::CONTACTS).unwrap();
    for (i, &n) in sizes.iter().enumerate() {
        let header = StepHeader { run_id: 1, simulation: 0, step: i as u32 };
        let items = contacts(n, i as u32);
        publisher.publish(&header, &items).unwrap();
        let got = sub.recv_timeout(Duration::from_secs(10)).unwrap().expect("frame arrives");
        assert_eq!(*got.header(), header);
        assert_eq!(got.items(), &items[..], "frame {i} with {n} contacts");
    }
    assert_eq!(sub.received(), sizes.len() as u64);
    assert_eq!(sub.decode_errors(), 0);
}

#[test]
fn iceoryx2_slices_grow_from_empty_to_30000_contacts() {
    round_trip(Transport::Iceoryx2, "grow", &[0, 1, 1000, 30_000, 5, 30_000]);
}

#[test]
fn zenoh_frames_round_trip_in_one_process() {
    round_trip(Transport::Zenoh, "zenoh", &[0, 3, 10_000]);
}

#[test]
fn a_zenoh_publisher_holds_its_first_frame_until_every_planned_subscriber_is_there() {
    // The publisher listens; one subscriber is there from the start, the second declares itself
    // 300 ms later. Told (as the launcher tells it) that two subscribers read the topic, the
    // publisher waits for both: the late one gets the first frame too.
    let base = bus("late-reader", Transport::Zenoh);
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut publisher_bus = base.clone();
    publisher_bus.zenoh.listen = vec![endpoint.clone()];
    publisher_bus.zenoh_readers = [(topics::CONTACTS.name.to_string(), 2)].into();
    let mut reader_bus = base;
    reader_bus.zenoh.connect = vec![endpoint];
    let writer = Node::new("writer", publisher_bus, false);
    let mut publisher = writer.publisher(topics::CONTACTS).unwrap();
    let early_node = Node::new("early", reader_bus.clone(), false);
    let mut early = early_node.subscriber(topics::CONTACTS).unwrap();
    let late = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(300));
        let node = Node::new("late", reader_bus, false);
        let mut late = node.subscriber(topics::CONTACTS).unwrap();
        let first = late.recv_timeout(Duration::from_secs(15)).unwrap().expect("a frame reaches the late subscriber");
        first.header().step
    });
    let started = std::time::Instant::now();
    for step in 0..3 {
        publisher.publish(&StepHeader { run_id: 1, simulation: 0, step }, &contacts(2, step)).unwrap();
    }
    let waited = started.elapsed();
    assert!(
        waited >= Duration::from_millis(250),
        "the first frame left after {waited:?}, before the second subscriber"
    );
    assert_eq!(early.recv_timeout(Duration::from_secs(5)).unwrap().expect("first frame").header().step, 0);
    assert_eq!(late.join().unwrap(), 0, "the late subscriber missed the first frame");
}

#[test]
fn zero_copy_publish_writes_in_place() {
    let bus = bus("inplace", Transport::Iceoryx2);
    let node = Node::new("both", bus, false);
    let mut sub = node.subscriber(topics::CONTACTS).unwrap();
    let mut publisher = node.publisher(topics::CONTACTS).unwrap();
    publisher
        .publish_with(4, |h, c| {
            h.step = 9;
            c.iter_mut().enumerate().for_each(|(i, c)| c.feature = i as u32 * 3)
        })
        .unwrap();
    let got = sub.recv_timeout(Duration::from_secs(5)).unwrap().unwrap();
    assert!(matches!(got, runtime::Received::Shared(_)), "iceoryx2 frames are read in place");
    assert_eq!(got.items().iter().map(|c| c.feature).collect::<Vec<_>>(), [0, 3, 6, 9]);
    assert_eq!(got.header().step, 9);
}

#[test]
fn receive_times_out_without_a_publisher() {
    let node = Node::new("lonely", bus("lonely", Transport::Iceoryx2), false);
    let mut sub = node.subscriber(topics::BODIES).unwrap();
    let start = std::time::Instant::now();
    assert!(sub.recv_timeout(Duration::from_millis(200)).unwrap().is_none());
    assert!(start.elapsed() >= Duration::from_millis(200));
}
