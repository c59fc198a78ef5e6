// The palp command: convert, inspect and generate volumes, benchmark ray bundles.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>
#include <vector>

#include "commands.h"
#include "palp/base/error.h"
#include "progress.h"

namespace palp::tool {
Globals& globals() {
    static Globals g;
    return g;
}
}  // namespace palp::tool

int main(int argc, char** argv) {
    CLI::App app{"palp: haptic volume palpation - convert scans, inspect volumes, make phantoms"};
    app.require_subcommand(1);
    app.set_version_flag("--version", "palp 0.1.0");
    app.add_flag("-q,--quiet", palp::tool::globals().quiet, "No progress output");
    std::vector<palp::tool::Command> commands{
        palp::tool::addConvert(app), palp::tool::addInfo(app), palp::tool::addPhantom(app),
        palp::tool::addBench(app), palp::tool::addPalpate(app)};
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        return app.exit(e);
    }
    try {
        for (auto& c : commands) {
            if (c.app->parsed()) return c.run();
        }
    } catch (const palp::Error& e) {
        palp::tool::endProgress();
        std::fprintf(stderr, "palp: error: %s\n", e.what());
        return 1;
    } catch (const std::exception& e) {
        palp::tool::endProgress();
        std::fprintf(stderr, "palp: error: %s\n", e.what());
        return 2;
    }
    return 1;
}
