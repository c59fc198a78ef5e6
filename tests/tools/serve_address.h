#pragma once
// `palp serve --listen 127.0.0.1:0 [--igtl-port 0]` binds ports the system chooses (never one
// guessed from the pid, which another process or another test may hold) and reports them on
// stderr: "palp serve: listening on udp HOST:PORT" right after binding, "palp serve: igtl on tcp
// PORT" once the stream listens. These helpers read those lines back.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

namespace palp::test {

/// Shell text that waits (up to 60 s: a loaded 2-core CI machine may be slow to start serve) for
/// serve's "listening on udp" line in @p errFile and sets $addr to its HOST:PORT; when none
/// comes it prints what serve wrote, kills the background job $serve and exits 99. @p who: the
/// command that prints the line ("palp serve", "palp study").
inline std::string shellAwaitServeAddress(const std::string& errFile,
                                          const std::string& who = "palp serve") {
    return "addr=; i=0; while [ $i -lt 1200 ]; do addr=$(sed -n 's/^" + who +
           ": listening on udp "
           "//p' " +
           errFile +
           "); [ -n \"$addr\" ] && break; kill -0 $serve 2>/dev/null || break; sleep 0.05; "
           "i=$((i+1)); done; if [ -z \"$addr\" ]; then echo 'serve reported no address:'; cat " +
           errFile + "; kill $serve 2>/dev/null; wait; exit 99; fi; ";
}

/// The rest of the first whole line of @p path that starts with @p prefix, waiting for it up to
/// @p seconds; "" when none came.
inline std::string awaitLine(const std::filesystem::path& path, const std::string& prefix,
                             double seconds) {
    const auto until = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    do {
        std::ifstream in(path);
        for (std::string line; std::getline(in, line);) {
            // A whole line only (not one still being written).
            if (line.rfind(prefix, 0) == 0 && !in.eof()) return line.substr(prefix.size());
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
    } while (std::chrono::steady_clock::now() < until);
    return "";
}

}  // namespace palp::test
