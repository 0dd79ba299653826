//! An independent Foxglove WebSocket client: the protocol from Foxglove's published spec
//! (subprotocol `foxglove.sdk.v1`: JSON `serverInfo` / `advertise` / `subscribe`, binary message
//! data `0x01 | u32 subscription | u64 log time | payload`) over tokio-tungstenite, and the few
//! fields of the well-known schemas it checks, as prost structs written from Foxglove's .proto files
//! (field numbers from `foxglove/SceneUpdate.proto`, `SceneEntity.proto`, `Grid.proto`, ...), not
//! the SDK's own types.

#![allow(dead_code)]

use futures_util::{SinkExt, StreamExt};
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
use tokio::net::TcpSocket;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

pub type Ws = WebSocketStream<MaybeTlsStream<tokio::net::TcpStream>>;

pub const SUBPROTOCOL: &str = "foxglove.sdk.v1";

/// `foxglove.SceneUpdate`: only the entities.
#[derive(Clone, PartialEq, prost::Message)]
pub struct SceneUpdate {
    #[prost(message, repeated, tag = "2")]
    pub entities: Vec<SceneEntity>,
}

/// `foxglove.SceneEntity`: time, id, frame, metadata, arrows, cubes, cylinders.
#[derive(Clone, PartialEq, prost::Message)]
pub struct SceneEntity {
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    #[prost(string, tag = "2")]
    pub frame_id: String,
    #[prost(string, tag = "3")]
    pub id: String,
    #[prost(message, repeated, tag = "6")]
    pub metadata: Vec<KeyValuePair>,
    #[prost(message, repeated, tag = "7")]
    pub arrows: Vec<Primitive>,
    #[prost(message, repeated, tag = "8")]
    pub cubes: Vec<Primitive>,
    #[prost(message, repeated, tag = "10")]
    pub cylinders: Vec<Primitive>,
}

/// `google.protobuf.Timestamp`, as Foxglove's schemas carry it.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Timestamp {
    #[prost(int64, tag = "1")]
    pub seconds: i64,
    #[prost(int32, tag = "2")]
    pub nanos: i32,
}

impl Timestamp {
    /// Nanoseconds since the epoch.
    pub fn ns(&self) -> u64 {
        self.seconds as u64 * 1_000_000_000 + self.nanos as u64
    }
}

/// `foxglove.KeyValuePair`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct KeyValuePair {
    #[prost(string, tag = "1")]
    pub key: String,
    #[prost(string, tag = "2")]
    pub value: String,
}

/// Any primitive (arrow, cube, cylinder): its pose, field 1 in all of them; the other fields are
/// skipped as unknown.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Primitive {
    #[prost(message, optional, tag = "1")]
    pub pose: Option<Pose>,
}

#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Pose {
    #[prost(message, optional, tag = "1")]
    pub position: Option<Vector3>,
    #[prost(message, optional, tag = "2")]
    pub orientation: Option<Quaternion>,
}

#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Vector3 {
    #[prost(double, tag = "1")]
    pub x: f64,
    #[prost(double, tag = "2")]
    pub y: f64,
    #[prost(double, tag = "3")]
    pub z: f64,
}

#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Quaternion {
    #[prost(double, tag = "1")]
    pub x: f64,
    #[prost(double, tag = "2")]
    pub y: f64,
    #[prost(double, tag = "3")]
    pub z: f64,
    #[prost(double, tag = "4")]
    pub w: f64,
}

/// `foxglove.Grid`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Grid {
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    #[prost(string, tag = "2")]
    pub frame_id: String,
    #[prost(fixed32, tag = "4")]
    pub column_count: u32,
    #[prost(fixed32, tag = "6")]
    pub row_stride: u32,
    #[prost(fixed32, tag = "7")]
    pub cell_stride: u32,
    #[prost(message, repeated, tag = "8")]
    pub fields: Vec<PackedElementField>,
    #[prost(bytes = "vec", tag = "9")]
    pub data: Vec<u8>,
}

/// `foxglove.PackedElementField`; `type` 7 is FLOAT32.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PackedElementField {
    #[prost(string, tag = "1")]
    pub name: String,
    #[prost(fixed32, tag = "2")]
    pub offset: u32,
    #[prost(int32, tag = "3")]
    pub r#type: i32,
}

pub const FLOAT32: i32 = 7;

/// `foxglove.RawImage`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct RawImage {
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    #[prost(fixed32, tag = "2")]
    pub width: u32,
    #[prost(fixed32, tag = "3")]
    pub height: u32,
    #[prost(string, tag = "4")]
    pub encoding: String,
    #[prost(fixed32, tag = "5")]
    pub step: u32,
    #[prost(bytes = "vec", tag = "6")]
    pub data: Vec<u8>,
}

/// One advertised channel.
#[derive(Debug, Clone)]
pub struct ChannelAd {
    pub id: u64,
    pub topic: String,
    pub encoding: String,
    pub schema_name: String,
    pub schema_encoding: String,
}

/// A connected client and what it has learnt.
pub struct Client {
    pub ws: Ws,
    pub server_info: Option<serde_json::Value>,
    pub channels: BTreeMap<String, ChannelAd>,
    /// Subscription id -> topic.
    pub subscriptions: BTreeMap<u32, String>,
    next_subscription: u32,
}

/// Message data of a subscription.
pub struct Data {
    pub topic: String,
    pub log_time: u64,
    pub payload: Vec<u8>,
}

/// Connects to `ws://127.0.0.1:port`, offering only `foxglove.sdk.v1`, retrying until `deadline`
/// (the server starts with the graph). `recv_buffer` shrinks the socket's receive buffer (a client
/// that never reads then fills up fast).
pub async fn connect(port: u16, deadline: Instant, recv_buffer: Option<u32>) -> Client {
    let url = format!("ws://127.0.0.1:{port}");
    loop {
        let socket = TcpSocket::new_v4().expect("socket");
        if let Some(size) = recv_buffer {
            socket.set_recv_buffer_size(size).expect("SO_RCVBUF");
        }
        match socket.connect(([127, 0, 0, 1], port).into()).await {
            Ok(stream) => {
                let mut request = url.as_str().into_client_request().expect("request");
                request.headers_mut().insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse().unwrap());
                let (ws, response) = tokio_tungstenite::client_async(request, MaybeTlsStream::Plain(stream))
                    .await
                    .expect("WebSocket handshake");
                let proto = response.headers().get("Sec-WebSocket-Protocol").map(|v| v.to_str().unwrap().to_string());
                assert_eq!(proto.as_deref(), Some(SUBPROTOCOL), "the server must accept {SUBPROTOCOL}");
                return Client {
                    ws,
                    server_info: None,
                    channels: BTreeMap::new(),
                    subscriptions: BTreeMap::new(),
                    next_subscription: 1,
                };
            }
            Err(e) => {
                assert!(Instant::now() < deadline, "no Foxglove server on port {port}: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    }
}

impl Client {
    /// Takes in a JSON (text) message: server info and channel advertisements.
    fn on_text(&mut self, text: &str) {
        let v: serde_json::Value = serde_json::from_str(text).expect("server messages are JSON");
        match v["op"].as_str() {
            Some("serverInfo") => self.server_info = Some(v),
            Some("advertise") => {
                for c in v["channels"].as_array().expect("advertise has channels") {
                    let ad = ChannelAd {
                        id: c["id"].as_u64().expect("channel id"),
                        topic: c["topic"].as_str().expect("topic").to_string(),
                        encoding: c["encoding"].as_str().unwrap_or_default().to_string(),
                        schema_name: c["schemaName"].as_str().unwrap_or_default().to_string(),
                        schema_encoding: c["schemaEncoding"].as_str().unwrap_or_default().to_string(),
                    };
                    self.channels.insert(ad.topic.clone(), ad);
                }
            }
            _ => {}
        }
    }

    /// The next message data; JSON messages on the way are taken in. `None` at `deadline` or when
    /// the server closes.
    pub async fn next_data(&mut self, deadline: Instant) -> Option<Data> {
        loop {
            let left = deadline.checked_duration_since(Instant::now())?;
            let msg = match tokio::time::timeout(left, self.ws.next()).await {
                Err(_) => return None,
                Ok(None) => return None,
                Ok(Some(Err(e))) => panic!("WebSocket error: {e}"),
                Ok(Some(Ok(m))) => m,
            };
            match msg {
                Message::Text(t) => self.on_text(t.as_str()),
                Message::Binary(b) => {
                    assert!(b.len() >= 13, "binary message too short");
                    if b[0] != 0x01 {
                        continue; // time, service responses, ...
                    }
                    let sub = u32::from_le_bytes(b[1..5].try_into().unwrap());
                    let log_time = u64::from_le_bytes(b[5..13].try_into().unwrap());
                    let topic = self.subscriptions.get(&sub).cloned().expect("data for a subscription we made");
                    return Some(Data { topic, log_time, payload: b[13..].to_vec() });
                }
                Message::Close(_) => return None,
                _ => {}
            }
        }
    }

    /// Reads JSON messages until `topics` are all advertised (or `deadline`: false).
    pub async fn wait_for_channels(&mut self, topics: &[&str], deadline: Instant) -> bool {
        while !topics.iter().all(|t| self.channels.contains_key(*t)) {
            let left = match deadline.checked_duration_since(Instant::now()) {
                Some(l) => l,
                None => return false,
            };
            match tokio::time::timeout(left, self.ws.next()).await {
                Ok(Some(Ok(Message::Text(t)))) => self.on_text(t.as_str()),
                Ok(Some(Ok(_))) => {}
                _ => return false,
            }
        }
        true
    }

    /// Subscribes to an advertised topic.
    pub async fn subscribe(&mut self, topic: &str) {
        let channel = self.channels.get(topic).unwrap_or_else(|| panic!("`{topic}` not advertised")).id;
        let id = self.next_subscription;
        self.next_subscription += 1;
        self.subscriptions.insert(id, topic.to_string());
        let msg = serde_json::json!({"op": "subscribe", "subscriptions": [{"id": id, "channelId": channel}]});
        self.ws.send(Message::Text(msg.to_string().into())).await.expect("send subscribe");
    }
}
