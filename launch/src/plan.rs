//! Routing a graph: which topics each node publishes and subscribes (asked of the node binaries),
//! which transport carries each topic between which nodes, and every node's bus configuration.
//!
//! Rule, per port: a publisher uses iceoryx2 when its topic has readers on its own host, zenoh
//! when it has readers on other hosts, both when both; a subscriber reads iceoryx2 from writers on
//! its host and zenoh from writers elsewhere. A topic forced in the file's `[topics]` uses the
//! forced transport on every port. Every host's launcher is a member too: it publishes `control`
//! (node down / up notices) and, on a graph of several hosts, meets the other launchers over zenoh.

use crate::graph::{run_check, Graph, GraphError, Problem};
use runtime::{BusConfig, Ports, Transport, ZenohConfig};
use std::collections::BTreeMap;

/// The graph member name of a host's launcher.
pub fn launcher_name(host: &str) -> String {
    format!("dc-launch-{host}")
}

/// One member of the bus: a node, or a host's launcher.
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    pub name: String,
    pub host: String,
    pub ports: Ports,
}

/// A routed graph.
#[derive(Debug, Clone)]
pub struct Plan {
    pub members: Vec<Member>,
    /// Transport of each (member, topic) port.
    pub transports: BTreeMap<(String, String), Transport>,
    /// zenoh listen endpoint of each member that uses zenoh (peer mesh).
    pub endpoints: BTreeMap<String, String>,
    /// The router's endpoint and host, when the graph names one.
    pub router: Option<(String, String)>,
    pub multi_host: bool,
    namespace: String,
    queue_depth: usize,
    /// Topics delivered best effort.
    pub best_effort: std::collections::BTreeSet<String>,
    /// TLS on every zenoh link.
    pub security: Option<crate::graph::Security>,
    extra_connect: BTreeMap<String, Vec<String>>,
    /// `(scheme, address)` of a router whose port the launcher picks (one host, no ports named).
    router_address: Option<(String, String)>,
}

/// The members that write and that read one topic on one host.
type TopicUsers<'a> = (Vec<&'a str>, Vec<&'a str>);

/// Asks each node binary for its ports (`DC_DESCRIBE=1`: it builds its ports from its
/// parameters, prints them and exits before touching the bus), through [`run_check`]: only dc's
/// own node binaries unless the graph is trusted, bounded in time and output.
pub fn describe_ports(graph: &Graph) -> Result<BTreeMap<String, Ports>, GraphError> {
    let mut out = BTreeMap::new();
    let mut problems = Vec::new();
    for node in &graph.nodes {
        let result = run_check(node, graph.trust, |command| {
            command
                .envs(&node.env)
                .env("DC_DESCRIBE", "1")
                .env("DC_NODE_NAME", &node.name)
                .env_remove("DC_LAUNCHED")
                .env_remove("DC_BUS");
        });
        let why = match result {
            Ok(o) => {
                let stdout = String::from_utf8_lossy(&o.stdout);
                let ports = stdout
                    .lines()
                    .find_map(|l| l.strip_prefix(runtime::PORTS_MARKER))
                    .map(serde_json::from_str::<Ports>);
                match (o.status.success(), ports) {
                    (true, Some(Ok(p))) => {
                        out.insert(node.name.clone(), p);
                        continue;
                    }
                    (true, Some(Err(e))) => format!("unreadable port list: {e}"),
                    (true, None) => {
                        "it exited without saying which topics it uses (it never reached `ready`)".to_string()
                    }
                    (false, _) => {
                        let stderr = String::from_utf8_lossy(&o.stderr);
                        let first = stderr.lines().find(|l| !l.trim().is_empty()).unwrap_or("").trim().to_string();
                        format!("it failed before starting ({}): {first}", o.status)
                    }
                }
            }
            Err(why) => why,
        };
        problems.push(Problem { line: node.line, message: format!("node `{}` ({}): {why}", node.name, node.binary) });
    }
    if problems.is_empty() {
        Ok(out)
    } else {
        Err(GraphError::Invalid { file: graph.file.clone(), problems })
    }
}

impl Plan {
    /// Routes `graph` given every node's ports.
    pub fn new(graph: &Graph, ports: &BTreeMap<String, Ports>) -> Plan {
        let multi_host = graph.hosts.len() > 1;
        let mut members = Vec::new();
        for host in graph.hosts.keys() {
            let launcher_ports =
                Ports { publishes: [msgs::topics::CONTROL.name.to_string()].into(), ..Default::default() };
            members.push(Member { name: launcher_name(host), host: host.clone(), ports: launcher_ports });
            for node in graph.nodes_on(host) {
                members.push(Member {
                    name: node.name.clone(),
                    host: host.clone(),
                    ports: ports.get(&node.name).cloned().unwrap_or_default(),
                });
            }
        }
        let mut transports = BTreeMap::new();
        for m in &members {
            for (topic, publishing) in
                m.ports.publishes.iter().map(|t| (t, true)).chain(m.ports.subscribes.iter().map(|t| (t, false)))
            {
                let t = match graph.topics.get(topic) {
                    Some(forced) => *forced,
                    None => {
                        // The other side of this port: readers of what we write, writers of what we read.
                        let peers = members.iter().filter(|o| {
                            if publishing {
                                o.ports.subscribes.contains(topic)
                            } else {
                                o.ports.publishes.contains(topic)
                            }
                        });
                        let (mut local, mut remote) = (false, false);
                        for o in peers {
                            if o.host == m.host {
                                local = true
                            } else {
                                remote = true
                            }
                        }
                        match (local, remote) {
                            (true, true) => Transport::Both,
                            (false, true) => Transport::Zenoh,
                            _ => Transport::Iceoryx2,
                        }
                    }
                };
                transports.insert((m.name.clone(), topic.clone()), t);
            }
        }
        let router = graph
            .hosts
            .values()
            .find(|h| h.router)
            .map(|h| (format!("{}/{}:{}", graph.link_scheme(), h.address, h.zenoh_port), h.name.clone()));
        let mut plan = Plan {
            members,
            transports,
            endpoints: BTreeMap::new(),
            router,
            multi_host,
            namespace: graph.namespace.clone(),
            queue_depth: graph.queue_depth,
            best_effort: graph.best_effort.clone(),
            security: graph.security.clone(),
            extra_connect: graph.hosts.iter().map(|(n, h)| (n.clone(), h.zenoh_connect.clone())).collect(),
            router_address: None,
        };
        let auto_port = graph.hosts.values().all(|h| h.zenoh_port == 0);
        if plan.router.is_none() && !multi_host && auto_port {
            // One host, no ports named: the launcher runs the graph's router on a port it binds
            // itself (retrying another if it was taken meanwhile, see `choose_router_port`); the
            // nodes listen on ports the system gives them and meet through it. Nodes listening on
            // ports picked for them could find one taken between the pick and their start.
            let zenoh_used = plan.members.iter().any(|m| plan.uses_zenoh(&m.name));
            if let Some(host) = graph.hosts.values().next().filter(|_| zenoh_used) {
                plan.router = Some((String::new(), host.name.clone()));
                plan.router_address = Some((graph.link_scheme().to_string(), host.address.clone()));
                plan.choose_router_port();
            }
        }
        if plan.router.is_none() {
            // Every machine computes the same ports from the file: members in file order per host.
            for (name, host) in &graph.hosts {
                let users: Vec<String> = plan
                    .members
                    .iter()
                    .filter(|m| &m.host == name && plan.uses_zenoh(&m.name))
                    .map(|m| m.name.clone())
                    .collect();
                for (i, member) in users.into_iter().enumerate() {
                    let port = host.zenoh_port + i as u16;
                    plan.endpoints.insert(member, format!("{}/{}:{port}", graph.link_scheme(), host.address));
                }
            }
        }
        plan
    }

    /// Refuses a graph whose members on one host need more writers, readers or processes on one
    /// topic than an iceoryx2 service is made for ([`runtime::MAX_PUBLISHERS`] ...): without
    /// this check the graph would pass `--dry-run` and fail at start with iceoryx2's
    /// `ExceedsMaxSupportedPublishers`, naming neither the topic nor the limit.
    pub fn check_port_limits(&self, graph: &Graph) -> Result<(), GraphError> {
        // (host, topic) -> its users over iceoryx2 ports.
        let mut use_of: BTreeMap<(&str, &str), TopicUsers> = BTreeMap::new();
        for m in &self.members {
            for (topic, writes) in
                m.ports.publishes.iter().map(|t| (t, true)).chain(m.ports.subscribes.iter().map(|t| (t, false)))
            {
                let local = self.transports.get(&(m.name.clone(), topic.clone())).is_none_or(|t| t.uses_iceoryx2());
                if !local {
                    continue;
                }
                let entry = use_of.entry((m.host.as_str(), topic.as_str())).or_default();
                if writes {
                    entry.0.push(&m.name)
                } else {
                    entry.1.push(&m.name)
                }
            }
        }
        let line_of = |member: &str| graph.nodes.iter().find(|n| n.name == member).map_or(1, |n| n.line);
        let mut problems = Vec::new();
        for ((host, topic), (writers, readers)) in &use_of {
            let processes: std::collections::BTreeSet<&str> = writers.iter().chain(readers).copied().collect();
            for (what, who, limit) in
                [("writers", writers, runtime::MAX_PUBLISHERS), ("readers", readers, runtime::MAX_SUBSCRIBERS)]
            {
                if who.len() > limit {
                    problems.push(Problem {
                        line: line_of(who[limit]),
                        message: format!(
                            "topic `{topic}` has {} {what} on host `{host}` ({}), iceoryx2 services here take at most {limit}: split the graph or use fewer simulators (`dc eval --jobs`)",
                            who.len(),
                            who.join(", ")
                        ),
                    });
                }
            }
            if processes.len() > runtime::MAX_NODES {
                problems.push(Problem {
                    line: 1,
                    message: format!(
                        "topic `{topic}` is used by {} processes on host `{host}`, at most {}",
                        processes.len(),
                        runtime::MAX_NODES
                    ),
                });
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(GraphError::Invalid { file: graph.file.clone(), problems })
        }
    }

    /// Gives the launcher-run router a port that is free now; true if the router's port is the
    /// launcher's to choose (else nothing changes). The launcher binds it at once and, should
    /// another process have taken it in between, calls this again: the nodes start only after.
    pub fn choose_router_port(&mut self) -> bool {
        let (Some((scheme, address)), Some((endpoint, _))) = (&self.router_address, &mut self.router) else {
            return false;
        };
        *endpoint = format!("{scheme}/{address}:{}", free_port(address));
        true
    }

    /// Whether `member` opens a zenoh session: a port over zenoh, or a launcher of a multi-host
    /// graph (it meets the other launchers).
    pub fn uses_zenoh(&self, member: &str) -> bool {
        let launcher = self.members.iter().any(|m| m.name == member && m.name == launcher_name(&m.host));
        (launcher && self.multi_host) || self.transports.iter().any(|((m, _), t)| m == member && t.uses_zenoh())
    }

    /// The TLS files of `host`'s nodes, when the graph is secured.
    pub fn tls_of(&self, host: &str) -> Option<runtime::TlsConfig> {
        self.security.as_ref().and_then(|s| s.of_host(host))
    }

    /// The bus configuration `member` (on `host`) receives.
    pub fn bus(&self, member: &str, host: &str) -> BusConfig {
        let topics = self
            .transports
            .iter()
            .filter(|((m, _), _)| m == member)
            .map(|((_, topic), t)| (topic.clone(), *t))
            .collect();
        let zenoh = match (&self.router, self.uses_zenoh(member)) {
            (_, false) => ZenohConfig::default(),
            // The launcher's own router (one host, no ports named): the nodes are peers that
            // listen on ports the system gives them and meet through the router, which tells
            // them of each other (gossip); data then goes peer to peer, as with named ports.
            (Some((endpoint, _)), true) if self.router_address.is_some() => {
                ZenohConfig { listen: vec![], connect: vec![endpoint.clone()], mode: None, tls: self.tls_of(host) }
            }
            (Some((endpoint, _)), true) => ZenohConfig {
                listen: vec![],
                connect: vec![endpoint.clone()],
                mode: Some("client".into()),
                tls: self.tls_of(host),
            },
            (None, true) => ZenohConfig {
                listen: self.endpoints.get(member).cloned().into_iter().collect(),
                // A full mesh: zenoh peers do not relay for third parties.
                connect: self
                    .endpoints
                    .iter()
                    .filter(|(m, _)| m.as_str() != member)
                    .map(|(_, e)| e.clone())
                    .chain(self.extra_connect.get(host).into_iter().flatten().cloned())
                    .collect(),
                mode: None,
                tls: self.tls_of(host),
            },
        };
        BusConfig {
            namespace: self.namespace.clone(),
            default_transport: Transport::Iceoryx2,
            topics,
            zenoh_readers: self.zenoh_readers(member),
            zenoh,
            queue_depth: self.queue_depth,
            best_effort: self.best_effort.clone(),
            host: if self.multi_host { host.to_string() } else { String::new() },
            observe: false,
        }
    }

    /// Per topic `member` publishes over zenoh: how many other members subscribe to it over zenoh
    /// (each announces itself; the publisher waits for all before its first frame).
    fn zenoh_readers(&self, member: &str) -> BTreeMap<String, usize> {
        let over_zenoh = |m: &str, topic: &str| {
            self.transports.get(&(m.to_string(), topic.to_string())).is_some_and(|t| t.uses_zenoh())
        };
        let Some(me) = self.members.iter().find(|m| m.name == member) else { return BTreeMap::new() };
        me.ports
            .publishes
            .iter()
            .filter(|topic| over_zenoh(member, topic))
            .map(|topic| {
                let readers = self
                    .members
                    .iter()
                    .filter(|o| o.name != member && o.ports.subscribes.contains(topic) && over_zenoh(&o.name, topic))
                    .count();
                (topic.clone(), readers)
            })
            .filter(|&(_, readers)| readers > 0)
            .collect()
    }

    /// Every topic with its writers and readers (`member@host`) and how each link travels.
    pub fn routes(&self) -> Vec<Route> {
        let mut topics: BTreeMap<&str, Route> = BTreeMap::new();
        for m in &self.members {
            for t in &m.ports.publishes {
                topics.entry(t).or_insert_with(|| Route::new(t)).writers.push((m.name.clone(), m.host.clone()));
            }
            for t in &m.ports.subscribes {
                topics.entry(t).or_insert_with(|| Route::new(t)).readers.push((m.name.clone(), m.host.clone()));
            }
        }
        for r in topics.values_mut() {
            let mut links = std::collections::BTreeSet::new();
            for (w, wh) in &r.writers {
                for (rd, rh) in &r.readers {
                    let wt = self.transports[&(w.clone(), r.topic.clone())];
                    let rt = self.transports[&(rd.clone(), r.topic.clone())];
                    let link = if wh == rh && wt.uses_iceoryx2() && rt.uses_iceoryx2() {
                        format!("iceoryx2 on {wh}")
                    } else if wt.uses_zenoh() && rt.uses_zenoh() {
                        if wh == rh {
                            format!("zenoh on {wh}")
                        } else {
                            format!("zenoh {wh} -> {rh}")
                        }
                    } else {
                        continue;
                    };
                    links.insert(link);
                }
            }
            r.links = links.into_iter().collect();
        }
        topics.into_values().collect()
    }
}

/// One topic of a routed graph.
#[derive(Debug, Clone, PartialEq)]
pub struct Route {
    pub topic: String,
    pub writers: Vec<(String, String)>,
    pub readers: Vec<(String, String)>,
    /// How the topic travels: `iceoryx2 on a`, `zenoh a -> b`, ...
    pub links: Vec<String>,
}

impl Route {
    fn new(topic: &str) -> Route {
        Route { topic: topic.to_string(), writers: vec![], readers: vec![], links: vec![] }
    }
}

pub fn free_port(address: &str) -> u16 {
    std::net::TcpListener::bind((address, 0)).and_then(|l| l.local_addr()).map(|a| a.port()).unwrap_or(7447)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ports(publishes: &[&str], subscribes: &[&str]) -> Ports {
        Ports {
            publishes: publishes.iter().map(|s| s.to_string()).collect(),
            subscribes: subscribes.iter().map(|s| s.to_string()).collect(),
        }
    }

    fn two_hosts(topics: &str) -> Graph {
        let text = format!(
            "[hosts.a]\naddress='10.1.0.1'\nzenoh_port=7600\n[hosts.b]\naddress='10.1.0.2'\nzenoh_port=7700\n{topics}\n\
             [[nodes]]\nname='sim'\nbinary='sh'\nhost='a'\n\
             [[nodes]]\nname='rec'\nbinary='sh'\nhost='a'\n\
             [[nodes]]\nname='sph'\nbinary='sh'\nhost='b'\n"
        );
        Graph::parse("g.toml", &text).unwrap()
    }

    fn node_ports() -> BTreeMap<String, Ports> {
        [
            ("sim".to_string(), ports(&["bodies", "control"], &["grid/contacts"])),
            ("rec".to_string(), ports(&[], &["bodies", "grid/contacts", "control"])),
            ("sph".to_string(), ports(&["grid/contacts"], &["bodies", "control"])),
        ]
        .into()
    }

    /// One host, zenoh forced, no port named: the launcher's router takes the only port picked
    /// (the launcher binds it before any node starts, and picks again if it was taken); the
    /// nodes listen on ports the system gives them and connect to it, so no node can lose a
    /// port race at start.
    #[test]
    fn one_host_without_ports_routes_zenoh_through_a_router_the_launcher_binds() {
        let text =
            "[topics]\nbodies = 'zenoh'\n[[nodes]]\nname='sim'\nbinary='sh'\n[[nodes]]\nname='rec'\nbinary='sh'\n";
        let graph = Graph::parse("g.toml", text).unwrap();
        let p = BTreeMap::from([
            ("sim".to_string(), ports(&["bodies"], &[])),
            ("rec".to_string(), ports(&[], &["bodies"])),
        ]);
        let mut plan = Plan::new(&graph, &p);
        let (endpoint, host) = plan.router.clone().expect("a router");
        assert_eq!(host, "local");
        let port: u16 = endpoint.strip_prefix("tcp/127.0.0.1:").expect(&endpoint).parse().unwrap();
        assert_ne!(port, 0);
        assert!(plan.endpoints.is_empty(), "no node listens: {:?}", plan.endpoints);
        for m in ["sim", "rec"] {
            // Peers on ports the system gives them (`listen` empty), meeting through the router.
            let z = plan.bus(m, "local").zenoh;
            assert_eq!((z.listen.len(), z.connect.clone(), z.mode.as_deref()), (0, vec![endpoint.clone()], None));
        }
        // Taken meanwhile: the launcher picks again, and the nodes are told the new one.
        let holder = std::net::TcpListener::bind(("127.0.0.1", port));
        assert!(plan.choose_router_port());
        let again = plan.router.clone().unwrap().0;
        assert_ne!(again, endpoint, "{holder:?}");
        assert_eq!(plan.bus("sim", "local").zenoh.connect, vec![again]);
        // Ports named in the file: peers on them, nothing for the launcher to choose.
        let named =
            Graph::parse("g.toml", &format!("[hosts.local]\naddress='127.0.0.1'\nzenoh_port=7600\n{text}")).unwrap();
        let mut plan = Plan::new(&named, &p);
        assert!(plan.router.is_none() && !plan.choose_router_port());
        assert_eq!(
            (plan.endpoints["sim"].as_str(), plan.endpoints["rec"].as_str()),
            ("tcp/127.0.0.1:7600", "tcp/127.0.0.1:7601")
        );
    }

    /// One host with `writers` simulators writing `control` (plus the launcher) and one reader.
    fn writers_of_control(writers: usize) -> (Graph, BTreeMap<String, Ports>) {
        let mut text = String::from("[[nodes]]\nname='metrics'\nbinary='sh'\n");
        let mut p = BTreeMap::from([("metrics".to_string(), ports(&[], &["control", "stats/solve"]))]);
        for i in 0..writers {
            text.push_str(&format!("[[nodes]]\nname='sim{i}'\nbinary='sh'\n"));
            p.insert(format!("sim{i}"), ports(&["control", "stats/solve"], &[]));
        }
        (Graph::parse("g.toml", &text).unwrap(), p)
    }

    /// The writers a service is made for, launcher included, are allowed; one more is refused
    /// naming the topic, the host, the count and the limit, on the line of the first writer
    /// past it.
    #[test]
    fn a_topic_with_more_writers_than_a_service_takes_is_refused_by_the_check() {
        let (graph, p) = writers_of_control(runtime::MAX_PUBLISHERS - 1);
        Plan::new(&graph, &p).check_port_limits(&graph).unwrap();
        let (graph, p) = writers_of_control(runtime::MAX_PUBLISHERS);
        let e = Plan::new(&graph, &p).check_port_limits(&graph).unwrap_err().to_string();
        let limit = runtime::MAX_PUBLISHERS;
        assert!(e.contains(&format!("topic `control` has {} writers on host `local`", limit + 1)), "{e}");
        assert!(e.contains(&format!("at most {limit}")) && e.contains("dc-launch-local, sim0"), "{e}");
        assert!(!e.contains("stats/solve"), "stats/solve has one writer fewer (no launcher): {e}");
    }

    #[test]
    fn topics_go_over_iceoryx2_within_a_host_zenoh_across_and_both_when_read_on_both() {
        let plan = Plan::new(&two_hosts(""), &node_ports());
        let t = |m: &str, topic: &str| plan.transports[&(m.to_string(), topic.to_string())];
        // bodies: read by rec (same host) and sph (other host): published once on each transport.
        assert_eq!(t("sim", "bodies"), Transport::Both);
        assert_eq!(t("rec", "bodies"), Transport::Iceoryx2);
        assert_eq!(t("sph", "bodies"), Transport::Zenoh);
        // grid/contacts: written on b only, read on a.
        assert_eq!(t("sph", "grid/contacts"), Transport::Zenoh);
        assert_eq!(t("sim", "grid/contacts"), Transport::Zenoh);
        // control: written by sim and both launchers, read on both hosts.
        assert_eq!(t("rec", "control"), Transport::Both);
        assert_eq!(t(&launcher_name("b"), "control"), Transport::Both);
        let routes = plan.routes();
        let bodies = routes.iter().find(|r| r.topic == "bodies").unwrap();
        assert_eq!(bodies.links, ["iceoryx2 on a", "zenoh a -> b"]);
    }

    #[test]
    fn publishers_know_how_many_subscribers_read_them_over_zenoh() {
        let plan = Plan::new(&two_hosts(""), &node_ports());
        let readers = |m: &str, host: &str| plan.bus(m, host).zenoh_readers.into_iter().collect::<Vec<_>>();
        // bodies: sph reads it over zenoh (rec over iceoryx2); control: rec (both) and sph.
        assert_eq!(readers("sim", "a"), [("bodies".to_string(), 1), ("control".to_string(), 2)]);
        // grid/contacts: sim and rec, both on the other host.
        assert_eq!(readers("sph", "b"), [("grid/contacts".to_string(), 2)]);
        assert!(readers("rec", "a").is_empty(), "rec publishes nothing");
    }

    #[test]
    fn endpoints_are_the_same_on_every_host_and_iceoryx2_names_carry_the_host() {
        let graph = two_hosts("");
        let a = Plan::new(&graph, &node_ports());
        let b = Plan::new(&graph, &node_ports());
        assert_eq!(a.endpoints, b.endpoints);
        assert_eq!(a.endpoints[&launcher_name("a")], "tcp/10.1.0.1:7600");
        assert_eq!(a.endpoints["sim"], "tcp/10.1.0.1:7601");
        // rec reads only local topics... and control from host b: it needs zenoh too.
        assert_eq!(a.endpoints["rec"], "tcp/10.1.0.1:7602");
        assert_eq!(a.endpoints["sph"], "tcp/10.1.0.2:7701");
        let bus = a.bus("sim", "a");
        assert_eq!(bus.host, "a");
        assert_eq!(bus.iox_key("bodies"), format!("dc/{}@a/bodies", graph.namespace));
        assert_eq!(bus.zenoh.listen, ["tcp/10.1.0.1:7601"]);
        assert_eq!(bus.zenoh.connect.len(), 4);
    }

    #[test]
    fn a_forced_transport_applies_to_every_port_and_a_router_replaces_the_mesh() {
        let mut graph = two_hosts("[topics]\n'bodies' = 'zenoh'");
        let plan = Plan::new(&graph, &node_ports());
        assert_eq!(plan.transports[&("rec".to_string(), "bodies".to_string())], Transport::Zenoh);
        graph.hosts.get_mut("b").unwrap().router = true;
        let plan = Plan::new(&graph, &node_ports());
        let bus = plan.bus("sph", "b");
        assert_eq!(bus.zenoh.mode.as_deref(), Some("client"));
        assert_eq!(bus.zenoh.connect, ["tcp/10.1.0.2:7700"]);
        assert!(bus.zenoh.listen.is_empty());
    }

    #[test]
    fn a_one_host_graph_stays_on_iceoryx2_with_unqualified_names() {
        let graph =
            Graph::parse("g.toml", "[[nodes]]\nname='sim'\nbinary='sh'\n[[nodes]]\nname='rec'\nbinary='sh'\n").unwrap();
        let p: BTreeMap<String, Ports> =
            [("sim".to_string(), ports(&["bodies"], &[])), ("rec".to_string(), ports(&[], &["bodies"]))].into();
        let plan = Plan::new(&graph, &p);
        assert!(plan.transports.values().all(|t| *t == Transport::Iceoryx2));
        assert!(plan.endpoints.is_empty());
        assert_eq!(plan.bus("sim", "local").host, "");
    }
}
