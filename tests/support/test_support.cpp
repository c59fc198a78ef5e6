#include "test_support.h"

#include <zlib.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <random>
#include <vector>

#include "memory_use.h"

namespace palp::test {

namespace fs = std::filesystem;

fs::path dataDir() {
    const char* env = std::getenv("PALP_DATA_DIR");
    const fs::path dir = env ? fs::path(env) : fs::path(PALP_DEFAULT_DATA_DIR);
    std::error_code ec;
    if (fs::is_directory(dir, ec)) return fs::canonical(dir);
    return {};
}

fs::path dataPath(const std::string& sub) {
    const fs::path root = dataDir();
    if (root.empty()) return {};
    const fs::path p = root / sub;
    return fs::exists(p) ? p : fs::path();
}

TempDir::TempDir() {
    std::random_device rd;
    mPath =
        fs::temp_directory_path() / ("palp-test-" + std::to_string(rd()) + std::to_string(rd()));
    fs::create_directories(mPath);
}

TempDir::~TempDir() {
    std::error_code ec;
    fs::remove_all(mPath, ec);
}

RunResult runCommand(const std::string& commandLine) {
    RunResult r;
    const std::string full = commandLine + " 2>&1";
    FILE* pipe = ::popen(full.c_str(), "r");
    if (!pipe) return r;
    std::array<char, 4096> buf{};
    std::size_t n = 0;
    while ((n = std::fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
    const int status = ::pclose(pipe);
    r.exitCode = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return r;
}

fs::path palpTool() {
    const char* bin = std::getenv("PALP_BIN_DIR");
    return fs::path(bin ? bin : PALP_DEFAULT_BIN_DIR) / "tools" / "palp";
}

std::pair<double, double> rssAndPeak() {
    std::ifstream in("/proc/self/status");
    std::string key;
    double rss = 0, hwm = 0;
    while (in >> key) {
        double kb = 0;
        if (key == "VmRSS:" && in >> kb) rss = kb * 1024;
        if (key == "VmHWM:" && in >> kb) hwm = kb * 1024;
        in.ignore(1 << 20, '\n');
    }
    return {rss, hwm};
}

bool haveProgram(const std::string& program) {
    return runCommand("command -v " + program + " >/dev/null").exitCode == 0;
}

void writeFile(const fs::path& path, const std::string& bytes) {
    std::ofstream out(path, std::ios::binary);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string deflateBytes(const std::string& data, bool gzip, int level) {
    z_stream zs{};
    EXPECT_EQ(deflateInit2(&zs, level, Z_DEFLATED, gzip ? 15 + 16 : 15, 8, Z_DEFAULT_STRATEGY),
              Z_OK);
    std::string out(deflateBound(&zs, static_cast<uLong>(data.size())) + 64, '\0');
    zs.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
    zs.avail_in = static_cast<uInt>(data.size());
    zs.next_out = reinterpret_cast<Bytef*>(out.data());
    zs.avail_out = static_cast<uInt>(out.size());
    EXPECT_EQ(deflate(&zs, Z_FINISH), Z_STREAM_END);
    out.resize(zs.total_out);
    deflateEnd(&zs);
    return out;
}

std::string floatsLE(const std::vector<float>& values) {
    std::string s(values.size() * 4, '\0');
    std::memcpy(s.data(), values.data(), s.size());
    return s;
}

}  // namespace palp::test
