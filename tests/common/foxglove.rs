//! A Foxglove WebSocket protocol client for the tests (`foxglove.sdk.v1`, the subprotocol of
//! the `foxglove` SDK's server): connect, read the channel advertisements, subscribe, read
//! message data. Written from the protocol's spec
//! (<https://github.com/foxglove/ws-protocol/blob/main/docs/spec.md>), independent of the
//! server's code.

use std::collections::HashMap;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use serde_json::Value;
use tungstenite::client::IntoClientRequest;
use tungstenite::http::HeaderValue;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

pub const SUBPROTOCOL: &str = "foxglove.sdk.v1";

/// One advertised channel.
#[derive(Debug, Clone)]
pub struct Channel {
    pub id: u64,
    pub topic: String,
    pub encoding: String,
    pub schema_name: String,
    pub schema_encoding: String,
    pub schema: String,
}

/// One message-data frame.
#[derive(Debug, Clone)]
pub struct MessageData {
    pub topic: String,
    pub log_time_ns: u64,
    pub payload: Vec<u8>,
}

pub struct Client {
    ws: WebSocket<MaybeTlsStream<TcpStream>>,
    pub channels: Vec<Channel>,
    /// subscription id -> topic
    subscriptions: HashMap<u32, String>,
    next_id: u32,
}

impl Client {
    /// Connects to `ws://address:port`, retrying while the server is not up yet, for at most
    /// `limit`.
    pub fn connect(address: &str, port: u16, limit: Duration) -> Client {
        let started = Instant::now();
        let url = format!("ws://{address}:{port}");
        loop {
            let mut request = url.as_str().into_client_request().expect("request");
            request.headers_mut().insert(
                "Sec-WebSocket-Protocol",
                HeaderValue::from_static(SUBPROTOCOL),
            );
            match tungstenite::connect(request) {
                Ok((ws, response)) => {
                    let chosen = response
                        .headers()
                        .get("Sec-WebSocket-Protocol")
                        .and_then(|v| v.to_str().ok())
                        .unwrap_or("");
                    assert_eq!(chosen, SUBPROTOCOL, "the server's subprotocol");
                    return Client {
                        ws,
                        channels: Vec::new(),
                        subscriptions: HashMap::new(),
                        next_id: 1,
                    };
                }
                Err(e) => {
                    assert!(
                        started.elapsed() < limit,
                        "could not connect to {url} within {limit:?}: {e}"
                    );
                    std::thread::sleep(Duration::from_millis(100));
                }
            }
        }
    }

    fn set_read_timeout(&mut self, timeout: Option<Duration>) {
        if let MaybeTlsStream::Plain(stream) = self.ws.get_mut() {
            stream.set_read_timeout(timeout).expect("read timeout");
        }
    }

    /// Reads one frame within `wait` (None when nothing came). Text frames update the channel
    /// list (`advertise`, `unadvertise`); binary message-data frames are returned.
    pub fn poll(&mut self, wait: Duration) -> Option<Result<MessageData, Value>> {
        self.set_read_timeout(Some(wait.max(Duration::from_millis(1))));
        let frame = match self.ws.read() {
            Ok(frame) => frame,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                return None
            }
            Err(e) => panic!("Foxglove WebSocket read: {e}"),
        };
        match frame {
            Message::Text(text) => {
                let value: Value = serde_json::from_str(&text).expect("JSON from the server");
                if value["op"] == "advertise" {
                    for c in value["channels"].as_array().expect("channels") {
                        let s = |k: &str| c[k].as_str().unwrap_or_default().to_string();
                        self.channels.push(Channel {
                            id: c["id"].as_u64().expect("channel id"),
                            topic: s("topic"),
                            encoding: s("encoding"),
                            schema_name: s("schemaName"),
                            schema_encoding: s("schemaEncoding"),
                            schema: s("schema"),
                        });
                    }
                }
                Some(Err(value))
            }
            Message::Binary(bytes) => {
                assert!(
                    bytes.len() >= 13,
                    "message data frame of {} bytes",
                    bytes.len()
                );
                if bytes[0] != 1 {
                    return Some(Err(Value::String(format!("binary opcode {}", bytes[0]))));
                }
                let sub = u32::from_le_bytes(bytes[1..5].try_into().unwrap());
                let log_time_ns = u64::from_le_bytes(bytes[5..13].try_into().unwrap());
                let topic = self
                    .subscriptions
                    .get(&sub)
                    .unwrap_or_else(|| panic!("message for unknown subscription {sub}"))
                    .clone();
                Some(Ok(MessageData {
                    topic,
                    log_time_ns,
                    payload: bytes[13..].to_vec(),
                }))
            }
            _ => Some(Err(Value::Null)),
        }
    }

    /// Waits (at most `limit`) until channels for every topic of `topics` are advertised.
    pub fn wait_for_channels(&mut self, topics: &[&str], limit: Duration) {
        let started = Instant::now();
        while !topics
            .iter()
            .all(|t| self.channels.iter().any(|c| c.topic == *t))
        {
            assert!(
                started.elapsed() < limit,
                "channels {topics:?} not advertised within {limit:?}; advertised: {:?}",
                self.channels.iter().map(|c| &c.topic).collect::<Vec<_>>()
            );
            self.poll(Duration::from_millis(100));
        }
    }

    pub fn channel(&self, topic: &str) -> &Channel {
        self.channels
            .iter()
            .find(|c| c.topic == topic)
            .unwrap_or_else(|| panic!("no channel {topic}"))
    }

    /// Subscribes to `topic`'s channel.
    pub fn subscribe(&mut self, topic: &str) {
        let channel_id = self.channel(topic).id;
        let id = self.next_id;
        self.next_id += 1;
        self.subscriptions.insert(id, topic.to_string());
        let msg = serde_json::json!({
            "op": "subscribe",
            "subscriptions": [{ "id": id, "channelId": channel_id }],
        });
        self.ws
            .send(Message::Text(msg.to_string().into()))
            .expect("send subscribe");
    }
}
