#pragma once
// `flowclip serve`: one port for REST (ServiceHub), the WebSocket frame
// stream (/api/sessions/{id}/stream) and the editor's static files. All of
// Boost.Beast lives in http_server.cpp (it is slow to compile).
//
// Threads: Asio threads only read, write and parse; REST handlers run on a
// small worker pool because some wait (an edit waits for its frame
// boundary, an export writes a file). Each stream keeps at most one frame in
// flight and re-reads the session's newest frame when the previous write
// completes, so a slow client gets the newest frame and the server never
// queues frames for it.
#include "service/rest_api.h"

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace fc::service {

struct ServerOptions {
  std::string host = "127.0.0.1";
  uint16_t port = 8080;                  // 0: any free port (see HttpServer::port)
  std::string webDir;                    // static files ("" or missing: none)
  std::string token;                     // non-empty: required on every /api request
  std::vector<std::string> allowOrigins; // besides same-origin, for WebSocket upgrades ("http://host:port")
  size_t maxBodyBytes = size_t(8) << 20; // REST bodies and WebSocket messages
  int ioThreads = 2;
  int workerThreads = 4;
};

// true for 127.0.0.0/8, ::1 and "localhost".
bool isLoopbackHost(const std::string& host);

class HttpServer {
 public:
  // Binds and listens; throws std::runtime_error naming host and port if it
  // cannot.
  HttpServer(ServiceHub& hub, ServerOptions options);
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  uint16_t port() const;  // the bound port
  // Serves until stop() (or SIGINT / SIGTERM when handleSignals) on the
  // calling thread plus ioThreads − 1 more.
  void run(bool handleSignals = true);
  void stop();  // any thread

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

// A minimal blocking WebSocket client of /api/sessions/{id}/stream, for
// benchmarks and C++ tests (the scripted clients are Python, tests/).
class StreamClient {
 public:
  // Connects and completes the upgrade; throws std::runtime_error on failure.
  StreamClient(const std::string& host, uint16_t port, const std::string& path, const std::string& token = {});
  ~StreamClient();
  StreamClient(const StreamClient&) = delete;
  StreamClient& operator=(const StreamClient&) = delete;
  // Blocks for the next binary message (false when the connection closed).
  bool read(std::string& message);
  void send(const uint8_t* data, size_t size);
  void close();

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace fc::service
