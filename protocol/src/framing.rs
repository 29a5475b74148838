//! The one encoding of the server ↔ controller stream: each message is a frame of a 4-byte
//! big-endian payload length followed by the message as UTF-8 JSON. JSON keeps the link
//! readable in a packet capture and for other labs' tools; the length prefix makes message
//! boundaries explicit on a byte stream.
//!
//! [`FrameCodec`] is the only reader and writer of frames: a `tokio_util` codec (use it
//! with `FramedRead`, `FramedWrite` or `Framed`) on top of `LengthDelimitedCodec`, and,
//! through [`BlockingFramed`], the same codec over `std::io` for blocking clients.
//!
//! Two kinds of failure, kept apart in the types:
//!
//! - a whole frame whose JSON is not a message ([`MalformedMessage`], the *item* of the
//!   decoder) leaves the stream intact: answer it (`rejected`) and read on;
//! - a length that is 0 or above [`MAX_FRAME`], a stream that ends inside a frame, or an
//!   I/O error ([`FrameError`], the decoder's *error*) means the stream can no longer be
//!   delimited: end the connection.
//!
//! ```no_run
//! # async fn link(stream: tokio::net::TcpStream) {
//! use bdft_protocol::framing::ServerCodec;
//! use bdft_protocol::server_to_controller::ServerToController;
//! use futures_util::{SinkExt, StreamExt};
//! use tokio_util::codec::{FramedRead, FramedWrite};
//!
//! let (rd, wr) = stream.into_split();
//! let mut rd = FramedRead::new(rd, ServerCodec::default());
//! let mut wr = FramedWrite::new(wr, ServerCodec::default());
//! wr.send(ServerToController::Status {}).await.unwrap();
//! while let Some(frame) = rd.next().await {
//!     match frame {
//!         Ok(Ok(_msg)) => { /* a ControllerToServer */ }
//!         Ok(Err(_malformed)) => { /* log it and go on */ }
//!         Err(_fatal) => break,
//!     }
//! }
//! # }
//! ```

use std::io::{Read, Write};
use std::marker::PhantomData;

use bytes::{Bytes, BytesMut};
use serde::Serialize;
use serde::de::DeserializeOwned;
use thiserror::Error;
use tokio_util::codec::{Decoder, Encoder, LengthDelimitedCodec, LengthDelimitedCodecError};

use crate::controller_to_server::ControllerToServer;
use crate::server_to_controller::ServerToController;

/// Largest payload accepted (a record chunk is about 100 KB).
pub const MAX_FRAME: usize = 8 << 20;

/// The stream cannot be delimited any more, or the connection failed: end it.
#[derive(Debug, Error)]
pub enum FrameError {
    #[error("frame of {size} bytes exceeds the {limit}-byte limit")]
    TooLarge { size: usize, limit: usize },
    #[error("empty frame")]
    Empty,
    #[error("the stream ended inside a frame")]
    Truncated,
    /// A message that cannot be written as JSON (never a protocol type).
    #[error("message not serializable: {0}")]
    Unserializable(serde_json::Error),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// A whole frame whose JSON is not a known message (unknown type, unknown or missing field,
/// wrong value). The stream stays usable.
#[derive(Debug, Error)]
#[error("malformed message: {0}")]
pub struct MalformedMessage(#[from] pub serde_json::Error);

/// What the decoder yields per frame.
pub type Decoded<In> = Result<In, MalformedMessage>;

/// Frames in, `In` messages out of the decoder; `Out` messages into the encoder.
pub struct FrameCodec<In, Out> {
    frames: LengthDelimitedCodec,
    /// Largest payload read: [`MAX_FRAME`], or less before a peer is authenticated.
    limit: usize,
    _messages: PhantomData<fn(Out) -> In>,
}

/// The server's end of the link: reads `ControllerToServer`, writes `ServerToController`.
pub type ServerCodec = FrameCodec<ControllerToServer, ServerToController>;
/// The controller's end of the link: reads `ServerToController`, writes `ControllerToServer`.
pub type ControllerCodec = FrameCodec<ServerToController, ControllerToServer>;

impl<In, Out> FrameCodec<In, Out> {
    pub fn new() -> Self {
        Self::with_limit(MAX_FRAME)
    }

    /// A codec that refuses frames above `limit` bytes from the length header alone, before
    /// buffering any of it (an unauthenticated peer's frames are kept small this way).
    pub fn with_limit(limit: usize) -> Self {
        Self {
            frames: LengthDelimitedCodec::builder()
                .big_endian()
                .length_field_length(4)
                .max_frame_length(limit)
                .new_codec(),
            limit,
            _messages: PhantomData,
        }
    }

    /// Changes the limit for the frames still to come (raised once the peer is known).
    pub fn set_limit(&mut self, limit: usize) {
        self.frames.set_max_frame_length(limit);
        self.limit = limit;
    }
}

impl<In, Out> Default for FrameCodec<In, Out> {
    fn default() -> Self {
        Self::new()
    }
}

impl<In, Out> Clone for FrameCodec<In, Out> {
    fn clone(&self) -> Self {
        Self {
            frames: self.frames.clone(),
            limit: self.limit,
            _messages: PhantomData,
        }
    }
}

impl<In, Out> std::fmt::Debug for FrameCodec<In, Out> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameCodec")
            .field("in", &std::any::type_name::<In>())
            .field("out", &std::any::type_name::<Out>())
            .finish()
    }
}

impl<In: DeserializeOwned, Out> Decoder for FrameCodec<In, Out> {
    type Item = Decoded<In>;
    type Error = FrameError;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Self::Item>, FrameError> {
        // On a bad length the header is still in `src`: read it for the message.
        let announced = src
            .get(..4)
            .map(|h| u32::from_be_bytes([h[0], h[1], h[2], h[3]]) as usize);
        match self.frames.decode(src) {
            Ok(None) => Ok(None),
            Ok(Some(payload)) if payload.is_empty() => Err(FrameError::Empty),
            Ok(Some(payload)) => Ok(Some(
                serde_json::from_slice(&payload).map_err(MalformedMessage),
            )),
            Err(e)
                if e.get_ref()
                    .is_some_and(|e| e.is::<LengthDelimitedCodecError>()) =>
            {
                Err(FrameError::TooLarge {
                    size: announced.unwrap_or(usize::MAX),
                    limit: self.limit,
                })
            }
            Err(e) => Err(FrameError::Io(e)),
        }
    }

    fn decode_eof(&mut self, src: &mut BytesMut) -> Result<Option<Self::Item>, FrameError> {
        match self.decode(src)? {
            Some(item) => Ok(Some(item)),
            None if src.is_empty() => Ok(None),
            None => Err(FrameError::Truncated),
        }
    }
}

/// Only by value: a second impl for `&Out` would make `SinkExt::flush` on a `FramedWrite`
/// ambiguous. [`BlockingFramed::send`] and [`encode`] take references.
impl<In, Out: Serialize> Encoder<Out> for FrameCodec<In, Out> {
    type Error = FrameError;

    fn encode(&mut self, msg: Out, dst: &mut BytesMut) -> Result<(), FrameError> {
        encode_with(&mut self.frames, &msg, dst)
    }
}

fn encode_with<T: Serialize + ?Sized>(
    frames: &mut LengthDelimitedCodec,
    msg: &T,
    dst: &mut BytesMut,
) -> Result<(), FrameError> {
    let json = serde_json::to_vec(msg).map_err(FrameError::Unserializable)?;
    if json.len() > MAX_FRAME {
        return Err(FrameError::TooLarge {
            size: json.len(),
            limit: MAX_FRAME,
        });
    }
    Encoder::<Bytes>::encode(frames, Bytes::from(json), dst)?;
    Ok(())
}

/// The frame of `msg` as bytes, written by the codec: for writers that queue bytes, and for
/// tests that put raw bytes on a stream.
pub fn encode<T: Serialize + ?Sized>(msg: &T) -> Result<Vec<u8>, FrameError> {
    let mut dst = BytesMut::new();
    encode_with(&mut FrameCodec::<(), ()>::new().frames, msg, &mut dst)?;
    Ok(dst.to_vec())
}

/// The codec over a blocking `std::io` stream (a `TcpStream`, a file, a `Cursor`): the
/// same decoding path as the async side, fed by `Read`, writing with `Write`.
pub struct BlockingFramed<S, In, Out> {
    io: S,
    codec: FrameCodec<In, Out>,
    buf: BytesMut,
    eof: bool,
}

impl<S, In, Out> std::fmt::Debug for BlockingFramed<S, In, Out> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BlockingFramed")
            .field("codec", &self.codec)
            .field("buffered", &self.buf.len())
            .field("eof", &self.eof)
            .finish()
    }
}

/// Bytes asked of the reader at a time.
const READ_CHUNK: usize = 64 * 1024;

impl<S, In, Out> BlockingFramed<S, In, Out> {
    pub fn new(io: S) -> Self {
        Self {
            io,
            codec: FrameCodec::new(),
            buf: BytesMut::new(),
            eof: false,
        }
    }

    pub fn get_ref(&self) -> &S {
        &self.io
    }

    /// The stream itself (to set timeouts, or write raw bytes: a write does not disturb
    /// what has been read and buffered).
    pub fn get_mut(&mut self) -> &mut S {
        &mut self.io
    }

    pub fn into_inner(self) -> S {
        self.io
    }
}

impl<S: Read, In: DeserializeOwned, Out> BlockingFramed<S, In, Out> {
    /// The next frame: `Ok(None)` at a clean end of stream, `Ok(Some(Err(_)))` for a frame
    /// that is not a message (read on), `Err` when the stream cannot go on. A read error
    /// (e.g. a timeout) loses nothing: what was buffered stays for the next call.
    pub fn recv(&mut self) -> Result<Option<Decoded<In>>, FrameError> {
        loop {
            if self.eof {
                return self.codec.decode_eof(&mut self.buf);
            }
            if let Some(item) = self.codec.decode(&mut self.buf)? {
                return Ok(Some(item));
            }
            let have = self.buf.len();
            self.buf.resize(have + READ_CHUNK, 0);
            let read = self.io.read(&mut self.buf[have..]);
            self.buf.truncate(have + *read.as_ref().unwrap_or(&0));
            match read {
                Ok(0) => self.eof = true,
                Ok(_) => {}
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(FrameError::Io(e)),
            }
        }
    }
}

impl<S: Write, In, Out: Serialize> BlockingFramed<S, In, Out> {
    /// Writes one message as one frame.
    pub fn send(&mut self, msg: &Out) -> Result<(), FrameError> {
        let mut dst = BytesMut::new();
        encode_with(&mut self.codec.frames, msg, &mut dst)?;
        self.io.write_all(&dst)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use futures_util::{SinkExt, StreamExt};
    use tokio_util::codec::{FramedRead, FramedWrite};

    use super::*;

    /// Both ends over an in-memory pipe, as the controller and the server use them.
    #[tokio::test(flavor = "current_thread")]
    async fn async_ends_exchange_messages_and_survive_a_malformed_frame() {
        let (a, b) = tokio::io::duplex(64);
        let chunky = ServerToController::AbortTrial {
            trial_id: 1,
            reason: "x".repeat(1000), // larger than the pipe: arrives in pieces
        };
        let sent = chunky.clone();
        let writer = tokio::spawn(async move {
            let mut server = FramedWrite::new(a, ServerCodec::default());
            server.send(sent).await.unwrap();
            tokio::io::AsyncWriteExt::write_all(server.get_mut(), b"\0\0\0\x02{}")
                .await
                .unwrap();
            server.send(ServerToController::Status {}).await.unwrap();
        });
        let mut controller = FramedRead::new(b, ControllerCodec::default());
        assert_eq!(controller.next().await.unwrap().unwrap().unwrap(), chunky);
        let malformed = controller.next().await.unwrap().unwrap().unwrap_err();
        assert!(
            malformed.to_string().contains("missing field `type`"),
            "{malformed}"
        );
        assert_eq!(
            controller.next().await.unwrap().unwrap().unwrap(),
            ServerToController::Status {}
        );
        writer.await.unwrap();
        assert!(controller.next().await.is_none(), "clean end");
    }

    #[tokio::test(flavor = "current_thread")]
    async fn an_oversized_length_ends_the_async_stream() {
        let (mut a, b) = tokio::io::duplex(64);
        let mut controller = FramedRead::new(b, ControllerCodec::default());
        tokio::io::AsyncWriteExt::write_all(&mut a, &u32::MAX.to_be_bytes())
            .await
            .unwrap();
        assert!(matches!(
            controller.next().await,
            Some(Err(FrameError::TooLarge { size, limit: MAX_FRAME })) if size == u32::MAX as usize
        ));
        assert!(
            controller.next().await.is_none(),
            "nothing after a broken length"
        );
    }

    /// Before authentication a peer's length header alone decides: a frame above the small
    /// limit is refused before any of it is buffered, and the limit can be raised later.
    #[tokio::test(flavor = "current_thread")]
    async fn a_lowered_limit_refuses_big_frames_from_the_header() {
        let (mut a, b) = tokio::io::duplex(64);
        let mut controller = FramedRead::new(b, ControllerCodec::with_limit(1024));
        tokio::io::AsyncWriteExt::write_all(&mut a, &2000u32.to_be_bytes())
            .await
            .unwrap();
        assert!(matches!(
            controller.next().await,
            Some(Err(FrameError::TooLarge {
                size: 2000,
                limit: 1024
            }))
        ));
        let mut codec = ControllerCodec::with_limit(16);
        codec.set_limit(MAX_FRAME);
        let frame = encode(&ServerToController::AbortTrial {
            trial_id: 1,
            reason: "x".repeat(100),
        })
        .unwrap();
        let mut src = BytesMut::from(&frame[..]);
        assert!(matches!(codec.decode(&mut src), Ok(Some(Ok(_)))));
    }

    #[test]
    fn a_message_larger_than_a_frame_is_not_sent() {
        let huge = ServerToController::AbortTrial {
            trial_id: 1,
            reason: "x".repeat(MAX_FRAME),
        };
        assert!(matches!(encode(&huge), Err(FrameError::TooLarge { .. })));
        let mut dst = BytesMut::new();
        assert!(ServerCodec::default().encode(huge, &mut dst).is_err());
        assert!(dst.is_empty(), "nothing half-written");
    }
}
