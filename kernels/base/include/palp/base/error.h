#pragma once
/// @file
/// palp's exception hierarchy, used at set-up and IO boundaries only (readers, writers, tools,
/// scene construction). Kernels, the servo path and FEM steps never throw.
///
/// Every message names the file or item, what was expected and what was found, e.g.
/// `scan.nhdr: expected 'sizes' with 3 positive integers, found '64 0 12'`.

#include <stdexcept>
#include <string>

namespace palp {

/// Base of all palp errors.
class Error : public std::runtime_error {
  public:
    using std::runtime_error::runtime_error;
};

/// A file or directory could not be opened, read or written.
class IoError : public Error {
  public:
    using Error::Error;
};

/// A file was readable but its content is not what its format requires.
class FormatError : public Error {
  public:
    using Error::Error;
};

/// A value (option, parameter, header field) is outside what palp accepts.
class ValueError : public Error {
  public:
    using Error::Error;
};

}  // namespace palp
