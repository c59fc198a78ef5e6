#pragma once
// OpenVDB's own exceptions stop at the volume module's public entry points (not installed).

#include <openvdb/Exceptions.h>

#include <new>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>

namespace palp::volume::detail {

/// Runs @p body; an openvdb::Exception it throws becomes @p ErrorT with the message
/// `<what>: expected <expected>, found OpenVDB's error '<text>'`, so the caller learns which
/// file or field it concerns ("Inversion of singular 3x3 matrix" alone names neither).
template <typename ErrorT, typename Body>
auto withVdbErrors(const std::string& what, std::string_view expected, Body&& body)
    -> decltype(std::forward<Body>(body)()) {
    try {
        return std::forward<Body>(body)();
    } catch (const openvdb::Exception& e) {
        throw ErrorT(what + ": expected " + std::string(expected) + ", found OpenVDB's error '" +
                     e.what() + "'");
    }
}

}  // namespace palp::volume::detail
