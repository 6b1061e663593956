// The HTTP and WebSocket server (Boost.Beast). One file because Beast and
// Asio, header-only and slow to compile, are included here and nowhere else.
#include "service/http_server.h"

#include "core/text.h"
#include "service/frame_encoding.h"

#include <boost/asio/dispatch.hpp>
#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/thread_pool.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/websocket.hpp>

#include <algorithm>
#include <deque>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>

namespace fc::service {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using json = nlohmann::json;

bool isLoopbackHost(const std::string& host) {
  if (host == "localhost" || host == "::1") return true;
  boost::system::error_code ec;
  const auto addr = net::ip::make_address(host, ec);
  return !ec && addr.is_loopback();
}

// What the server keeps of each open stream, to let go of its session at
// shutdown (after the I/O threads have stopped, before the event loop dies).
struct StreamHandle {
  virtual ~StreamHandle() = default;
  virtual void releaseAtShutdown() = 0;
};

struct HttpServer::Impl {
  ServiceHub& hub;
  ServerOptions options;
  net::io_context ioc;
  tcp::acceptor acceptor;
  net::thread_pool workers;
  std::optional<net::signal_set> signals;
  std::mutex streamsMutex;
  std::vector<std::weak_ptr<StreamHandle>> streams;
  std::optional<net::steady_timer> acceptRetry;

  void addStream(const std::shared_ptr<StreamHandle>& s) {
    std::lock_guard lk(streamsMutex);
    std::erase_if(streams, [](const auto& w) { return w.expired(); });
    streams.push_back(s);
  }
  void releaseStreams() {
    std::vector<std::weak_ptr<StreamHandle>> all;
    {
      std::lock_guard lk(streamsMutex);
      all.swap(streams);
    }
    for (auto& w : all)
      if (auto s = w.lock()) s->releaseAtShutdown();
  }

  Impl(ServiceHub& h, ServerOptions o)
      : hub(h), options(std::move(o)), ioc(std::max(1, options.ioThreads)), acceptor(ioc),
        workers(size_t(std::max(1, options.workerThreads))) {}

  void accept();
  bool authorized(const std::string& authorization) const {
    return options.token.empty() || authorization == "Bearer " + options.token;
  }
  // On a loopback bind the Host header must name the loopback too: a page
  // whose DNS name was rebound to 127.0.0.1 sends its own name and is refused.
  bool hostAllowed(std::string host) const {
    if (!isLoopbackHost(options.host)) return true;
    if (!host.empty() && host.front() == '[') host = host.substr(1, host.find(']') - 1);
    else host = host.substr(0, host.find(':'));
    return host == "localhost" || isLoopbackHost(host);
  }
  // Same-origin (the Origin's host:port equals the Host header) or listed.
  bool originAllowed(const std::string& origin, const std::string& host) const {
    if (origin.empty()) return true;  // not a browser: nothing to protect against
    if (std::find(options.allowOrigins.begin(), options.allowOrigins.end(), origin) != options.allowOrigins.end())
      return true;
    const size_t scheme = origin.find("://");
    return scheme != std::string::npos && origin.substr(scheme + 3) == host;
  }
};

namespace {

using StringResponse = http::response<http::string_body>;

StringResponse makeResponse(const HttpResponse& r, unsigned version, bool keepAlive) {
  StringResponse res{http::status(r.status), version};
  res.set(http::field::server, "flowclip/" FLOWCLIP_VERSION);
  res.set(http::field::content_type, r.contentType);
  res.set(http::field::cache_control, "no-store");
  for (const auto& [k, v] : r.headers) res.set(k, v);
  res.keep_alive(keepAlive);
  res.body() = r.body;
  res.prepare_payload();
  return res;
}

const char* mimeType(const std::string& ext) {
  static const std::map<std::string, const char*> types = {
      {".html", "text/html; charset=utf-8"}, {".js", "text/javascript"},  {".mjs", "text/javascript"},
      {".css", "text/css"},                  {".json", "application/json"}, {".svg", "image/svg+xml"},
      {".png", "image/png"},                 {".ico", "image/x-icon"},    {".wasm", "application/wasm"},
      {".map", "application/json"},          {".txt", "text/plain"},      {".woff2", "font/woff2"}};
  auto it = types.find(ext);
  return it == types.end() ? "application/octet-stream" : it->second;
}

HttpResponse staticFile(const std::string& webDir, const std::string& target) {
  namespace fs = std::filesystem;
  if (webDir.empty()) return errorResponse(404, "no editor here: the server was started without --web");
  std::string path = target;
  if (path.empty() || path == "/") path = "/index.html";
  // Every segment must be an ordinary name: no "..", no hidden files.
  fs::path file(webDir);
  size_t i = 1;
  while (i <= path.size()) {
    const size_t j = std::min(path.find('/', i), path.size());
    const std::string seg = path.substr(i, j - i);
    if (!seg.empty()) {
      if (seg[0] == '.' || seg.find('\\') != std::string::npos || seg.find('%') != std::string::npos)
        return errorResponse(400, "invalid path " + printable(target, 120));
      file /= seg;
    }
    i = j + 1;
  }
  if (fs::is_directory(file)) file /= "index.html";
  std::ifstream in(file, std::ios::binary);
  if (!in) return errorResponse(404, "no file " + printable(target, 120));
  HttpResponse r;
  r.contentType = mimeType(file.extension().string());
  r.body.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  return r;
}

// application/json, or for PATCH (a JSON merge patch, RFC 7396) also
// application/merge-patch+json; parameters such as charset may follow.
bool jsonContentType(const std::string& contentType, http::verb method) {
  std::string type = contentType.substr(0, contentType.find(';'));
  type.erase(type.find_last_not_of(" \t") + 1);
  std::transform(type.begin(), type.end(), type.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return type == "application/json" || (method == http::verb::patch && type == "application/merge-patch+json");
}

// "/api/sessions/{id}/stream" → id (empty if the path is something else).
std::string streamSessionId(const std::string& path) {
  static const std::string prefix = "/api/sessions/", suffix = "/stream";
  if (path.size() <= prefix.size() + suffix.size() || path.compare(0, prefix.size(), prefix) != 0 ||
      path.compare(path.size() - suffix.size(), suffix.size(), suffix) != 0)
    return {};
  const std::string id = path.substr(prefix.size(), path.size() - prefix.size() - suffix.size());
  return id.find('/') == std::string::npos ? id : std::string();
}

// The token offered as the WebSocket subprotocol "flowclip-token.T" (browsers
// cannot set an Authorization header on a WebSocket).
std::string offeredTokenProtocol(const std::string& protocols, const std::string& token) {
  size_t i = 0;
  while (i < protocols.size()) {
    size_t j = protocols.find(',', i);
    if (j == std::string::npos) j = protocols.size();
    std::string p = protocols.substr(i, j - i);
    p.erase(0, p.find_first_not_of(' '));
    p.erase(p.find_last_not_of(' ') + 1);
    // Without a token on the server any offered token protocol is accepted
    // (and must be echoed, or the browser fails the handshake).
    if (p.rfind("flowclip-token.", 0) == 0 && (token.empty() || p == "flowclip-token." + token)) return p;
    i = j + 1;
  }
  return {};
}

// ---- WebSocket stream ------------------------------------------------------------

class StreamConnection : public StreamHandle, public std::enable_shared_from_this<StreamConnection> {
 public:
  // More unanswered acks and errors than this means the client does not
  // read: it is disconnected rather than buffered for.
  static constexpr size_t kMaxQueuedMessages = 256;
  // Stall, idle and close limits: ServiceOptions::stream*.

  StreamConnection(tcp::socket socket, HttpServer::Impl& server, std::shared_ptr<Session> session)
      : ws_(std::move(socket)), server_(server), session_(std::move(session)), timer_(ws_.get_executor()),
        stallTimer_(ws_.get_executor()) {}

  ~StreamConnection() override {
    // Normally released already; a connection dropped with the event loop
    // must still never be called by its session again.
    if (session_) {
      session_->unsubscribe(listenerId_);
      server_.hub.cancelOnSessionDeleted(deletionHook_);
    }
  }

  // Server shutdown, I/O threads stopped: nothing runs on the strand.
  void releaseAtShutdown() override { release(); }

  void start(http::request<http::string_body> req, std::string protocol) {
    // A peer that vanished answers no ping: dropped after the idle timeout.
    websocket::stream_base::timeout timeouts = websocket::stream_base::timeout::suggested(beast::role_type::server);
    timeouts.idle_timeout = server_.hub.options().streamIdleTimeout;
    timeouts.keep_alive_pings = true;
    ws_.set_option(timeouts);
    ws_.set_option(websocket::stream_base::decorator([protocol](websocket::response_type& res) {
      res.set(http::field::server, "flowclip/" FLOWCLIP_VERSION);
      if (!protocol.empty()) res.set(http::field::sec_websocket_protocol, protocol);
    }));
    ws_.read_message_max(server_.options.maxBodyBytes);
    ws_.binary(true);
    ws_.async_accept(req, [self = shared_from_this()](beast::error_code ec) { self->onAccept(ec); });
  }

 private:
  void onAccept(beast::error_code ec) {
    if (ec) return;
    std::weak_ptr<StreamConnection> weak = shared_from_this();
    auto onStrand = [weak](auto fn) {
      if (auto self = weak.lock()) net::post(self->ws_.get_executor(), [self, fn = std::move(fn)]() mutable { fn(*self); });
    };
    SessionListener listener;
    listener.frame = [onStrand](const FramePtr&) {
      onStrand([](StreamConnection& c) {
        c.framePending_ = true;
        c.pump();
      });
    };
    listener.edit = [onStrand](const EditResult& r) { onStrand([r](StreamConnection& c) { c.onEditResult(r); }); };
    listener.state = [onStrand](const json& state) {
      onStrand([state](StreamConnection& c) {
        c.pendingState_ = state;
        c.pump();
      });
    };
    listenerId_ = session_->subscribe(std::move(listener));
    deletionHook_ = server_.hub.onSessionDeleted(session_->id(), [weak] {
      if (auto self = weak.lock())
        net::post(self->ws_.get_executor(), [self] { self->closeWith("the session was deleted"); });
    });
    pendingState_ = session_->state();
    framePending_ = true;
    pump();
    read();
  }

  void read() {
    ws_.async_read(in_, [self = shared_from_this()](beast::error_code ec, size_t) { self->onRead(ec); });
  }

  void onRead(beast::error_code ec) {
    if (ec) {
      release();
      return;
    }
    if (!ws_.got_binary()) {
      queueError(wire::fb::ErrorCode::InvalidMessage,
                 "text messages are not understood: send binary flatbuffers (proto/flowclip.fbs, Envelope)", 0);
    } else if (session_) {
      const auto* data = static_cast<const uint8_t*>(in_.data().data());
      // Nothing a client sends may escape into the event loop.
      try {
        handle(wire::parseClientMessage(data, in_.size()));
      } catch (const std::exception& err) {
        queueError(wire::fb::ErrorCode::Internal, std::string("internal error: ") + err.what(), 0);
      } catch (...) {
        queueError(wire::fb::ErrorCode::Internal, "internal error", 0);
      }
    }
    in_.consume(in_.size());
    if (!closed_) read();
  }

  void handle(const wire::ClientMessage& message) {
    if (const auto* f = std::get_if<wire::ParseFailure>(&message)) {
      queueError(f->code, f->message, f->requestId);
    } else if (const auto* e = std::get_if<wire::EditRequest>(&message)) {
      try {
        Edit edit = Edit::fromJson(parseJsonLimited(e->json));
        const EditTicket t = session_->submit(std::move(edit));
        editIds_[t.id] = e->editId;
      } catch (const SessionOverloaded& err) {
        queueError(wire::fb::ErrorCode::Overloaded, err.what(), e->editId);
      } catch (const std::exception& err) {
        queueError(wire::fb::ErrorCode::InvalidEdit, err.what(), e->editId);
      }
    } else if (const auto* t = std::get_if<wire::TransportRequest>(&message)) {
      try {
        switch (t->command) {
          case wire::fb::TransportCommand::Play: session_->play(t->until); break;
          case wire::fb::TransportCommand::Pause: session_->pause(); break;
          case wire::fb::TransportCommand::Step: session_->step(int(t->steps)); break;
          case wire::fb::TransportCommand::Reset: session_->reset(); break;
          case wire::fb::TransportCommand::Seek: session_->seek(t->frame); break;
          case wire::fb::TransportCommand::SetSpeed: session_->setPlaybackSpeed(t->speed); break;
        }
        // Every transport is answered with the state it leaves (even when
        // nothing changed), carrying its request id.
        pendingState_ = session_->state();
        pendingRequest_ = t->requestId;
        pump();
      } catch (const std::out_of_range& err) {
        queueError(wire::fb::ErrorCode::NotFound, err.what(), t->requestId);
      } catch (const SessionError& err) {
        queueError(wire::fb::ErrorCode::Conflict, err.what(), t->requestId);
      } catch (const std::exception& err) {
        queueError(wire::fb::ErrorCode::InvalidArgument, err.what(), t->requestId);
      }
    } else if (const auto* s = std::get_if<wire::SubscribeRequest>(&message)) {
      maxFrameRate_ = s->maxFrameRate > 0 ? std::max(s->maxFrameRate, 0.01) : 0.0;
      session_->demandLayers(s->layers, +1);
      session_->demandLayers(layers_, -1);
      layers_ = s->layers;
      // The current frame again with the new layers: optional layers come
      // from the session (at once if encoded, else once it has encoded them:
      // no plain copy first), the rest is encoded here.
      layeredSent_ = nullptr;
      if (!(layers_.control || layers_.repulsion || layers_.boundary)) lastSent_ = nullptr;
      framePending_ = true;
      pump();
    }
  }

  void onEditResult(const EditResult& r) {
    auto it = editIds_.find(r.id);
    if (it == editIds_.end()) return;  // another client's (or REST's) edit: the state change tells
    const uint32_t clientId = it->second;
    editIds_.erase(it);
    if (r.accepted) {
      wire::buildAck(scratch_, clientId, r.frame);
      queue(scratch_);
    } else {
      queueError(wire::fb::ErrorCode::InvalidEdit, r.message, clientId);
    }
  }

  void queueError(wire::fb::ErrorCode code, const std::string& message, uint32_t requestId) {
    wire::buildError(scratch_, code, message, requestId);
    queue(scratch_);
  }

  void queue(const flatbuffers::FlatBufferBuilder& fbb) {
    if (messages_.size() >= kMaxQueuedMessages) {
      closeWith("the client does not read its messages");
      return;
    }
    messages_.emplace_back(reinterpret_cast<const char*>(fbb.GetBufferPointer()), fbb.GetSize());
    pump();
  }

  // Sends what is due, one message at a time: state first (coalesced to the
  // newest), then acks and errors in order, then the newest frame.
  void pump() {
    if (writing_ || closed_ || !session_) return;
    if (pendingState_) {
      wire::buildStateChange(scratch_, stateChangeInfo(*pendingState_, pendingRequest_));
      pendingState_.reset();
      pendingRequest_ = 0;
      current_.assign(reinterpret_cast<const char*>(scratch_.GetBufferPointer()), scratch_.GetSize());
      write(net::buffer(current_));
      return;
    }
    if (!messages_.empty()) {
      current_ = std::move(messages_.front());
      messages_.pop_front();
      write(net::buffer(current_));
      return;
    }
    if (!framePending_) return;
    const auto now = std::chrono::steady_clock::now();
    if (maxFrameRate_ > 0 && now < nextFrameAt_) {
      if (!timerArmed_) {
        timerArmed_ = true;
        timer_.expires_at(nextFrameAt_);
        timer_.async_wait([self = shared_from_this()](beast::error_code) {
          self->timerArmed_ = false;
          self->pump();
        });
      }
      return;
    }
    framePending_ = false;
    FramePtr f = session_->latestFrame();
    if (!f) return;
    // With optional layers: the bytes the session encoded for this frame
    // (the union of every stream's layers). Frame numbers identify it: a
    // replayed older frame never matches, a reset clears the history. The
    // layered version may arrive after the plain one was sent (a paused
    // session asked for a layer): it is sent then.
    std::shared_ptr<const LayeredFrame> layered;
    if (layers_.control || layers_.repulsion || layers_.boundary) {
      layered = session_->layeredFrame();
      if (layered && (layered->frame != f->frame || layered == layeredSent_)) layered.reset();
    }
    if (f == lastSent_ && !layered) return;
    if (maxFrameRate_ > 0) nextFrameAt_ = now + std::chrono::microseconds(int64_t(1e6 / maxFrameRate_));
    if (layered) {
      lastSent_ = f;
      layeredSent_ = layered;
      inFlight_ = std::move(layered);  // owns the bytes until the write completes
      write(net::buffer(inFlight_->envelope.data(), inFlight_->envelope.size()));
      return;
    }
    try {
      encodeSnapshot(*f, session_->id(), layers_, frameBuffer_);
    } catch (const std::exception& e) {
      queueError(wire::fb::ErrorCode::Internal,
                 "frame " + std::to_string(f->frame) + " cannot be encoded: " + e.what(), 0);
      return;
    }
    lastSent_ = f;
    write(net::buffer(frameBuffer_.GetBufferPointer(), frameBuffer_.GetSize()));
  }

  void write(net::const_buffer buffer) {
    writing_ = true;
    armStallTimer(server_.hub.options().streamWriteStall);
    ws_.async_write(buffer, [self = shared_from_this()](beast::error_code ec, size_t) {
      self->endWrite();
      self->inFlight_.reset();
      if (ec) {
        self->release();
        return;
      }
      self->pump();
    });
  }

  void closeWith(const std::string& reason) {
    if (closed_) return;
    release();
    // A close frame cannot be queued behind a write the peer does not take.
    if (writing_) {
      cut();
      return;
    }
    writing_ = true;
    armStallTimer(server_.hub.options().streamCloseGrace);
    ws_.async_close(websocket::close_reason(websocket::close_code::going_away, printable(reason, 120)),
                    [self = shared_from_this()](beast::error_code) { self->endWrite(); });
  }

  // A write or close completed: its stall timer no longer applies.
  void endWrite() {
    writing_ = false;
    ++stallSeq_;
    stallTimer_.cancel();
  }

  // Fires `after` from now unless the write or close in progress ends first.
  void armStallTimer(std::chrono::milliseconds after) {
    const uint64_t seq = ++stallSeq_;
    stallTimer_.expires_after(after);
    stallTimer_.async_wait([weak = weak_from_this(), seq](beast::error_code ec) {
      auto self = weak.lock();
      if (ec || !self || self->stallSeq_ != seq || !self->writing_) return;
      self->release();
      self->cut();
    });
  }

  // Closes the socket without a handshake: pending operations end with an error.
  void cut() {
    beast::error_code ignored;
    beast::get_lowest_layer(ws_).socket().shutdown(tcp::socket::shutdown_both, ignored);
    beast::get_lowest_layer(ws_).socket().close(ignored);
  }

  // Lets go of the session (its memory is freed once every holder has).
  void release() {
    if (closed_) return;
    closed_ = true;
    timer_.cancel();
    if (session_) {
      session_->demandLayers(layers_, -1);
      session_->unsubscribe(listenerId_);
      server_.hub.cancelOnSessionDeleted(deletionHook_);
      // The last owner of a deleted session joins its thread, which waits for
      // the frame in progress: never on an I/O thread.
      net::post(server_.workers, [s = std::move(session_)] {});
    }
    lastSent_.reset();
    messages_.clear();
  }

  websocket::stream<beast::tcp_stream> ws_;
  HttpServer::Impl& server_;
  std::shared_ptr<Session> session_;
  net::steady_timer timer_;
  net::steady_timer stallTimer_;  // armStallTimer
  uint64_t stallSeq_ = 0;
  beast::flat_buffer in_;
  flatbuffers::FlatBufferBuilder frameBuffer_{1 << 16};
  flatbuffers::FlatBufferBuilder scratch_{1024};
  std::string current_;
  std::deque<std::string> messages_;
  std::optional<json> pendingState_;
  uint32_t pendingRequest_ = 0;
  std::unordered_map<uint64_t, uint32_t> editIds_;  // session edit id → the client's Edit.edit_id
  FramePtr lastSent_;
  std::shared_ptr<const LayeredFrame> layeredSent_;  // the last layered frame sent (dedup)
  std::shared_ptr<const LayeredFrame> inFlight_;     // the layered frame being written
  bool framePending_ = false, writing_ = false, closed_ = false, timerArmed_ = false;
  double maxFrameRate_ = 0;
  std::chrono::steady_clock::time_point nextFrameAt_{};
  wire::LayerFlags layers_;
  uint64_t listenerId_ = 0, deletionHook_ = 0;
};

// ---- HTTP connection ----------------------------------------------------------------

class HttpConnection : public std::enable_shared_from_this<HttpConnection> {
 public:
  HttpConnection(tcp::socket socket, HttpServer::Impl& server) : stream_(std::move(socket)), server_(server) {}

  void start() {
    net::dispatch(stream_.get_executor(), [self = shared_from_this()] { self->read(); });
  }

 private:
  void read() {
    parser_.emplace();
    parser_->body_limit(server_.options.maxBodyBytes);
    parser_->header_limit(32 * 1024);
    stream_.expires_after(std::chrono::seconds(120));
    http::async_read(stream_, buffer_, *parser_,
                     [self = shared_from_this()](beast::error_code ec, size_t) { self->onRead(ec); });
  }

  void onRead(beast::error_code ec) {
    if (ec == http::error::end_of_stream) {
      stream_.socket().shutdown(tcp::socket::shutdown_send, ec);
      return;
    }
    if (ec == http::error::body_limit) {
      send(makeResponse(errorResponse(413, "the request body exceeds the server's limit of " +
                                               std::to_string(server_.options.maxBodyBytes) + " bytes (--max-body-mb)"),
                        11, false));
      return;
    }
    if (ec) {
      // A parse error gets an answer; a dropped connection does not.
      if (ec.category() == beast::error_code(http::error::bad_target).category())
        send(makeResponse(errorResponse(400, std::string("malformed HTTP request: ") + ec.message()), 11, false));
      return;
    }
    http::request<http::string_body> req = parser_->release();
    const std::string target(req.target());
    const std::string path = target.substr(0, target.find('?'));
    if (websocket::is_upgrade(req)) {
      upgrade(std::move(req), path);
      return;
    }
    // The health check answers at once, even with every worker busy.
    if (path == "/api/health" && (req.method() == http::verb::get || req.method() == http::verb::head)) {
      send(answer(req, target, path));
      return;
    }
    // REST handlers may wait (edits, exports): run them off the I/O threads,
    // with no deadline (send() sets one for the answer).
    stream_.expires_never();
    net::post(server_.workers, [self = shared_from_this(), req = std::move(req), target, path]() mutable {
      StringResponse res = self->answer(req, target, path);
      net::post(self->stream_.get_executor(), [self, res = std::move(res)]() mutable { self->send(std::move(res)); });
    });
  }

  // respond() as the wire answer; nothing it throws escapes the calling thread.
  StringResponse answer(const http::request<http::string_body>& req, const std::string& target,
                        const std::string& path) {
    HttpResponse r;
    try {
      r = respond(req, target, path);
    } catch (const std::exception& e) {
      r = errorResponse(500, std::string("internal error: ") + e.what());
    } catch (...) {
      r = errorResponse(500, "internal error");
    }
    StringResponse res = makeResponse(r, req.version(), req.keep_alive());
    if (req.method() == http::verb::head) res.body().clear();
    return res;
  }

  HttpResponse respond(const http::request<http::string_body>& req, const std::string& target, const std::string& path) {
    const bool api = path == "/api" || path.rfind("/api/", 0) == 0;
    if (!api) {
      if (req.method() != http::verb::get && req.method() != http::verb::head)
        return errorResponse(405, "only GET is served outside /api");
      return staticFile(server_.options.webDir, path);
    }
    if (!server_.authorized(std::string(req[http::field::authorization])))
      return errorResponse(401, "this server requires a token: send \"Authorization: Bearer <token>\"");
    if (!server_.hostAllowed(std::string(req[http::field::host])))
      return errorResponse(403, "Host " + printable(std::string(req[http::field::host]), 80) + " is not this server's loopback address");
    // A cross-site page may send simple requests without asking: refuse
    // foreign origins, and bodies that are not declared JSON (a form or
    // text/plain post cannot set that type without a preflight).
    if (!server_.originAllowed(std::string(req[http::field::origin]), std::string(req[http::field::host])))
      return errorResponse(403, "Origin " + printable(std::string(req[http::field::origin]), 80) +
                                    " is not allowed (same origin or --allow-origin)");
    if (!req.body().empty() && !jsonContentType(std::string(req[http::field::content_type]), req.method()))
      return errorResponse(415, "request bodies must be JSON, sent with Content-Type: application/json "
                                "(PATCH also takes application/merge-patch+json)");
    HttpRequest r;
    r.method = std::string(req.method_string());
    r.path = path;
    const size_t q = target.find('?');
    if (q != std::string::npos) r.query = target.substr(q + 1);
    for (const auto& field : req) {
      std::string name(field.name_string());
      std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return char(std::tolower(c)); });
      r.headers[name] = std::string(field.value());
    }
    r.body = req.body();
    return server_.hub.handle(r);
  }

  void upgrade(http::request<http::string_body> req, const std::string& path) {
    const unsigned version = req.version();
    const std::string id = streamSessionId(path);
    if (id.empty()) {
      send(makeResponse(errorResponse(404, "WebSocket streams are at /api/sessions/{id}/stream"), version, false));
      return;
    }
    const std::string protocol =
        offeredTokenProtocol(std::string(req[http::field::sec_websocket_protocol]), server_.options.token);
    if (!server_.authorized(std::string(req[http::field::authorization])) && protocol.empty()) {
      send(makeResponse(errorResponse(401, "this server requires a token: send \"Authorization: Bearer <token>\" "
                                           "or the WebSocket subprotocol flowclip-token.<token>"),
                        version, false));
      return;
    }
    if (!server_.hostAllowed(std::string(req[http::field::host]))) {
      send(makeResponse(errorResponse(403, "Host " + printable(std::string(req[http::field::host]), 80) +
                                               " is not this server's loopback address"),
                        version, false));
      return;
    }
    if (!server_.originAllowed(std::string(req[http::field::origin]), std::string(req[http::field::host]))) {
      send(makeResponse(errorResponse(403, "WebSocket origin " + printable(std::string(req[http::field::origin]), 80) +
                                               " is not allowed (same origin or --allow-origin)"),
                        version, false));
      return;
    }
    auto session = server_.hub.session(id);
    if (!session) {
      send(makeResponse(errorResponse(404, "no session \"" + printable(id, 80) + "\""), version, false));
      return;
    }
    stream_.expires_never();
    auto conn = std::make_shared<StreamConnection>(stream_.release_socket(), server_, std::move(session));
    server_.addStream(conn);
    conn->start(std::move(req), protocol);
  }

  void send(StringResponse res) {
    // A minute plus one second per MB for the answer to leave.
    stream_.expires_after(std::chrono::seconds(60 + res.body().size() / (1 << 20)));
    auto sp = std::make_shared<StringResponse>(std::move(res));
    http::async_write(stream_, *sp, [self = shared_from_this(), sp](beast::error_code ec, size_t) {
      if (ec) return;
      if (!sp->keep_alive()) {
        beast::error_code ignored;
        self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
        return;
      }
      self->read();
    });
  }

  beast::tcp_stream stream_;
  HttpServer::Impl& server_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
};

}  // namespace

void HttpServer::Impl::accept() {
  acceptor.async_accept(net::make_strand(ioc), [this](beast::error_code ec, tcp::socket socket) {
    if (!acceptor.is_open()) return;
    if (!ec) {
      std::make_shared<HttpConnection>(std::move(socket), *this)->start();
      accept();
      return;
    }
    // Out of descriptors, say: retry shortly instead of spinning.
    acceptRetry.emplace(ioc, std::chrono::milliseconds(100));
    acceptRetry->async_wait([this](beast::error_code e) {
      if (!e) accept();
    });
  });
}

HttpServer::HttpServer(ServiceHub& hub, ServerOptions options) : impl_(std::make_unique<Impl>(hub, std::move(options))) {
  const std::string where = impl_->options.host + ":" + std::to_string(impl_->options.port);
  beast::error_code ec;
  std::string host = impl_->options.host == "localhost" ? "127.0.0.1" : impl_->options.host;
  const auto address = net::ip::make_address(host, ec);
  if (ec) throw std::runtime_error("cannot listen on " + where + ": not an IP address");
  const tcp::endpoint endpoint(address, impl_->options.port);
  impl_->acceptor.open(endpoint.protocol(), ec);
  if (!ec) impl_->acceptor.set_option(net::socket_base::reuse_address(true), ec);
  if (!ec) impl_->acceptor.bind(endpoint, ec);
  if (!ec) impl_->acceptor.listen(net::socket_base::max_listen_connections, ec);
  if (ec) throw std::runtime_error("cannot listen on " + where + ": " + ec.message());
  impl_->accept();
}

HttpServer::~HttpServer() {
  stop();
  impl_->workers.join();
}

uint16_t HttpServer::port() const { return impl_->acceptor.local_endpoint().port(); }

void HttpServer::run(bool handleSignals) {
  if (handleSignals) {
    impl_->signals.emplace(impl_->ioc, SIGINT, SIGTERM);
    impl_->signals->async_wait([this](beast::error_code ec, int) {
      if (!ec) stop();
    });
  }
  std::vector<std::thread> threads;
  for (int i = 1; i < impl_->options.ioThreads; ++i) threads.emplace_back([this] { impl_->ioc.run(); });
  impl_->ioc.run();
  for (auto& t : threads) t.join();
  // Nothing runs on the event loop now: streams let go of their sessions
  // here, so no session thread ever touches a connection or the loop again.
  impl_->releaseStreams();
}

void HttpServer::stop() {
  net::post(impl_->ioc, [impl = impl_.get()] {
    beast::error_code ec;
    impl->acceptor.close(ec);
    if (impl->signals) impl->signals->cancel(ec);
  });
  impl_->ioc.stop();
}

// ---- blocking client ------------------------------------------------------------------

struct StreamClient::Impl {
  net::io_context ioc;
  websocket::stream<tcp::socket> ws{ioc};
};

StreamClient::StreamClient(const std::string& host, uint16_t port, const std::string& path, const std::string& token)
    : impl_(std::make_unique<Impl>()) {
  try {
    tcp::resolver resolver(impl_->ioc);
    net::connect(impl_->ws.next_layer(), resolver.resolve(host, std::to_string(port)));
    impl_->ws.read_message_max(size_t(1) << 30);
    if (!token.empty())
      impl_->ws.set_option(websocket::stream_base::decorator(
          [token](websocket::request_type& req) { req.set(http::field::authorization, "Bearer " + token); }));
    impl_->ws.handshake(host + ":" + std::to_string(port), path);
    impl_->ws.binary(true);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot open ws://" + host + ":" + std::to_string(port) + path + ": " + e.what());
  }
}

StreamClient::~StreamClient() { close(); }

bool StreamClient::read(std::string& message) {
  beast::flat_buffer buffer;
  beast::error_code ec;
  impl_->ws.read(buffer, ec);
  if (ec) return false;
  message.assign(static_cast<const char*>(buffer.data().data()), buffer.size());
  return true;
}

void StreamClient::send(const uint8_t* data, size_t size) { impl_->ws.write(net::buffer(data, size)); }

void StreamClient::close() {
  if (!impl_ || !impl_->ws.is_open()) return;
  beast::error_code ec;
  impl_->ws.close(websocket::close_code::normal, ec);
}

}  // namespace fc::service
