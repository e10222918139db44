# Precompiled headers (UAVM_PCH, on by default): the third-party headers nearly every source includes are parsed once
# per build tree instead of once per source. Parsing them was most of the build: OpenCV, Eigen, nlohmann/json,
# spdlog and GoogleTest take 1.5-3.5 s each per source with g++ 12, and a test source includes four of them.
# One PCH for the libraries and programs (uavm_pch) and one with GoogleTest for the tests (uavm_pch_test, in
# tests/); every other target reuses them (REUSE_FROM), so a tree compiles each PCH once.
# Only headers without macros that could clash are in it: no Ceres (glog's CHECK/LOG), GDAL or CLI11.
option(UAVM_PCH "Precompile the common third-party headers once per build tree" ON)

set(UAVM_PCH_HEADERS
  <algorithm> <array> <chrono> <cmath> <cstdint> <cstdio> <filesystem> <fstream> <functional> <map> <memory>
  <mutex> <optional> <random> <sstream> <string> <thread> <unordered_map> <vector>
  <Eigen/Core> <Eigen/Dense> <Eigen/Geometry>
  <opencv2/core.hpp> <opencv2/imgproc.hpp> <opencv2/imgcodecs.hpp>
  <nlohmann/json.hpp> <spdlog/spdlog.h>)

# What compiling against the PCH needs: the headers' include directories and their compile definitions (spdlog's
# SPDLOG_FMT_EXTERNAL and SPDLOG_COMPILED_LIB change what spdlog.h declares, so every user must see the same ones).
add_library(uavm_pch_deps INTERFACE)
target_link_libraries(uavm_pch_deps INTERFACE opencv_core opencv_imgproc opencv_imgcodecs Eigen3::Eigen
  nlohmann_json::nlohmann_json spdlog::spdlog)

# uavm_pch_owner(NAME HEADERS ... [DEPS ...]): a target that only compiles a PCH for others to reuse.
function(uavm_pch_owner name)
  cmake_parse_arguments(ARG "" "" "HEADERS;DEPS" ${ARGN})
  add_library(${name} OBJECT ${PROJECT_SOURCE_DIR}/cmake/pch_anchor.cpp)
  target_link_libraries(${name} PRIVATE uavm_pch_deps uavm_warnings ${ARG_DEPS})
  target_precompile_headers(${name} PRIVATE ${ARG_HEADERS})
endfunction()

# uavm_use_pch(TARGET [OWNER]): TARGET compiles with OWNER's PCH (default uavm_pch).
function(uavm_use_pch target)
  set(owner uavm_pch)
  if(ARGC GREATER 1)
    set(owner ${ARGV1})
  endif()
  target_link_libraries(${target} PRIVATE uavm_pch_deps)
  if(UAVM_PCH)
    target_precompile_headers(${target} REUSE_FROM ${owner})
  endif()
endfunction()

if(UAVM_PCH)
  uavm_pch_owner(uavm_pch HEADERS ${UAVM_PCH_HEADERS})
endif()
