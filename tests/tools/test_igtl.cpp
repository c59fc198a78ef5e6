// `palp serve --igtl-port` read by a client built on libopenigtlink while `palp bridge-sim`
// presses the avc phantom: TRANSFORM ProxyToRAS and DeviceToRAS, SENSOR Force (3 values, N) and
// STATUS Safety (the faults since the last frame: none but stale ticks here) arrive in that
// order each frame; the poses are RAS millimetres of the session's LPS metres (the proxy rests
// on the skin at LPS y = 0, so RAS y = 0; the pressed device lies deeper, RAS y < 0), the force
// of each frame is VC's k (proxy - device) of the same frame, and the device's orientation is
// the one the hand sends, in RAS axes. serve's UDP and TCP ports are the system's choice (port
// 0), read back from its stderr lines.
#include <gtest/gtest.h>
#include <igtlClientSocket.h>
#include <igtlMath.h>
#include <igtlMessageHeader.h>
#include <igtlSensorMessage.h>
#include <igtlStatusMessage.h>
#include <igtlTransformMessage.h>

#include <Eigen/Core>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>

#include "serve_address.h"
#include "test_support.h"

namespace {

struct Frame {
    Eigen::Vector3d proxy{Eigen::Vector3d::Constant(NAN)}, device{Eigen::Vector3d::Constant(NAN)};
    Eigen::Matrix3d deviceRotation{Eigen::Matrix3d::Constant(NAN)};
    Eigen::Vector3d force{Eigen::Vector3d::Constant(NAN)};
};

Eigen::Vector3d translation(igtl::TransformMessage* t) {
    igtl::Matrix4x4 m;
    t->GetMatrix(m);
    return {m[0][3], m[1][3], m[2][3]};
}

Eigen::Matrix3d rotation(igtl::TransformMessage* t) {
    igtl::Matrix4x4 m;
    t->GetMatrix(m);
    Eigen::Matrix3d r;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r(i, j) = m[i][j];
    return r;
}

TEST(Igtl, ServeStreamsProxyDeviceAndForceInRas) {
    palp::test::TempDir tmp;
    const std::string palp = palp::test::palpTool().string();
    const std::string err = (tmp / "serve.err").string();
    palp::test::RunResult run;
    std::thread tools([&] {
        run = palp::test::runCommand(
            palp +
            " serve --phantom avc --mode vc --k-base 300 --listen 127.0.0.1:0 --seconds 2.5 "
            "--watchdog-ms 500 --watchdog-grace-ms 400 --igtl-port 0 --igtl-rate 50 --json > " +
            (tmp / "serve.json").string() + " 2> " + err + " & serve=$!; " +
            palp::test::shellAwaitServeAddress(err) + palp +
            " bridge-sim --connect $addr --depth 7 --hold 0.8 --orientation "
            "0.7071067811865476,0,0,0.7071067811865476 > " +
            (tmp / "sim.txt").string() + " 2>&1; s=$?; wait; exit $s");
    });
    // The stream listens before the session starts (and before bridge-sim's press).
    const std::string port = palp::test::awaitLine(err, "palp serve: igtl on tcp ", 60);
    if (port.empty()) {
        tools.join();
        FAIL() << "serve reported no igtl port: " << run.output;
    }
    const int tcp = std::stoi(port);
    EXPECT_GT(tcp, 0);
    igtl::ClientSocket::Pointer socket = igtl::ClientSocket::New();
    bool connected = false;
    for (int i = 0; i < 100 && !connected; ++i) {
        connected = socket->ConnectToServer("127.0.0.1", tcp) == 0;
        if (!connected) std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    if (!connected) tools.join();
    ASSERT_TRUE(connected) << run.output;
    socket->SetReceiveTimeout(3000);
    int frames = 0, pressed = 0, exact = 0, order = 0, statuses = 0, cut = 0, ok = 0;
    Frame f;
    for (;;) {
        igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
        header->InitPack();
        if (socket->Receive(header->GetPackPointer(), header->GetPackSize()) !=
            header->GetPackSize())
            break;  // serve closed the stream
        header->Unpack();
        const std::string type = header->GetDeviceType();
        const std::string name = header->GetDeviceName();
        if (type == "TRANSFORM") {
            auto t = igtl::TransformMessage::New();
            t->SetMessageHeader(header);
            t->AllocatePack();
            socket->Receive(t->GetPackBodyPointer(), t->GetPackBodySize());
            ASSERT_TRUE(t->Unpack(1) & igtl::MessageHeader::UNPACK_BODY);
            if (name == "ProxyToRAS") {
                EXPECT_EQ(order, 0);
                f.proxy = translation(t);
                order = 1;
            } else {
                EXPECT_EQ(name, "DeviceToRAS");
                EXPECT_EQ(order, 1);
                f.device = translation(t);
                f.deviceRotation = rotation(t);
                order = 2;
            }
        } else if (type == "STATUS") {
            // STATUS Safety closes each frame: the faults since the last frame.
            EXPECT_EQ(name, "Safety");
            EXPECT_EQ(order, 3);
            auto st = igtl::StatusMessage::New();
            st->SetMessageHeader(header);
            st->AllocatePack();
            socket->Receive(st->GetPackBodyPointer(), st->GetPackBodySize());
            ASSERT_TRUE(st->Unpack(1) & igtl::MessageHeader::UNPACK_BODY);
            const int code = st->GetCode();
            const auto bits = static_cast<std::uint64_t>(st->GetSubCode());
            EXPECT_TRUE(code == igtl::StatusMessage::STATUS_OK ||
                        code == igtl::StatusMessage::STATUS_UNKNOWN_ERROR ||
                        code == igtl::StatusMessage::STATUS_DISABLED)
                << code;
            EXPECT_EQ(bits & ~std::uint64_t{63}, 0u);  // DeviceFault bits only
            if (code == igtl::StatusMessage::STATUS_OK) {
                EXPECT_EQ(bits, 0u);
            }
            // The press's states are good: stale ticks at most (before and after the hand).
            EXPECT_EQ(bits & ~std::uint64_t{1}, 0u) << st->GetStatusString();
            if (code == igtl::StatusMessage::STATUS_DISABLED) ++cut;
            if (code == igtl::StatusMessage::STATUS_OK) ++ok;
            ++statuses;
            order = 0;
        } else {
            ASSERT_EQ(type, "SENSOR");
            EXPECT_EQ(name, "Force");
            EXPECT_EQ(order, 2);
            auto s = igtl::SensorMessage::New();
            s->SetMessageHeader(header);
            s->AllocatePack();
            socket->Receive(s->GetPackBodyPointer(), s->GetPackBodySize());
            ASSERT_TRUE(s->Unpack(1) & igtl::MessageHeader::UNPACK_BODY);
            ASSERT_EQ(s->GetLength(), 3u);
            f.force = {s->GetValue(0), s->GetValue(1), s->GetValue(2)};
            order = 3;
            ++frames;
            // Pressed frames: the device below the skin (RAS y < -0.5 mm) with the gate open.
            if (f.device.y() < -0.5 && f.force.norm() > 0.05) {
                ++pressed;
                EXPECT_NEAR(f.proxy.y(), 0.0, 0.5);  // on the skin iso-surface, mm
                // VC: F = k (proxy - device), RAS N and mm (floats of mm: 1e-4 mm).
                // A hand process starved of CPU for longer than the watchdog's grace gets its
                // force scaled down (never up, never turned): the frame's force is then
                // s k (proxy - device) with 0 < s < 1. Most frames are whole.
                const Eigen::Vector3d want = 300.0 * (f.proxy - f.device) * 1e-3;
                EXPECT_NEAR((f.force.normalized() - want.normalized()).norm(), 0.0, 1e-3)
                    << "force " << f.force.transpose() << " want " << want.transpose();
                EXPECT_LE(f.force.norm(), want.norm() + 1e-3);
                if ((f.force - want).norm() < 1e-3) ++exact;
                // The hand's orientation, 90 degrees about z in palp's LPS world, in RAS axes:
                // diag(-1, -1, 1) Rz(90) = [[0 1 0] [-1 0 0] [0 0 1]].
                Eigen::Matrix3d ras;
                ras << 0, 1, 0, -1, 0, 0, 0, 0, 1;
                EXPECT_NEAR((f.deviceRotation - ras).cwiseAbs().maxCoeff(), 0.0, 1e-6)
                    << f.deviceRotation;
            }
        }
    }
    tools.join();
    std::printf("igtl: %d frames, %d pressed, %d with the whole force; status: %d ok, %d cut\n",
                frames, pressed, exact, ok, cut);
    EXPECT_EQ(run.exitCode, 0) << run.output;
    std::ifstream in(tmp / "serve.json");
    const std::string json((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    EXPECT_NE(json.find("\"port\": " + port), std::string::npos) << json;  // the bound one
    EXPECT_GT(frames, 50);                                                 // 2.5 s at 50 Hz
    EXPECT_GT(pressed, 10);
    EXPECT_GT(exact, pressed / 2);
    EXPECT_GE(statuses, frames - 1);  // one per frame (the last may have been cut off)
    EXPECT_GT(ok, 0);                 // during the press
}

}  // namespace
