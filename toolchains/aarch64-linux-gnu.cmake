# Cross build for aarch64 Linux companion computers (Raspberry Pi 4/5, Jetson-class), from Debian 12's
# crossbuild-essential-arm64 against an arm64 sysroot folder made by scripts/make_sysroot.sh.
#
#   cmake --preset aarch64-release                      (CMakePresets.json), or
#   cmake -S . -B build-aarch64 -DCMAKE_TOOLCHAIN_FILE=toolchains/aarch64-linux-gnu.cmake [-DUAVM_SYSROOT=DIR]
#
# UAVM_SYSROOT (cache variable or environment) names the sysroot; default /var/cache/uavmosaic/sysroot-arm64-bookworm.
# UAVM_AARCH64_CPU (e.g. cortex-a72, cortex-a76) adds -mcpu= for one board; empty builds for any ARMv8-A.
# Tests run through qemu-aarch64 (CMAKE_CROSSCOMPILING_EMULATOR), so `ctest` works unchanged on an x86 host.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)

if(NOT UAVM_SYSROOT)
  if(DEFINED ENV{UAVM_SYSROOT})
    set(UAVM_SYSROOT "$ENV{UAVM_SYSROOT}")
  else()
    set(UAVM_SYSROOT "/var/cache/uavmosaic/sysroot-arm64-bookworm")
  endif()
endif()
set(UAVM_SYSROOT "${UAVM_SYSROOT}" CACHE PATH "arm64 sysroot (scripts/make_sysroot.sh)")
if(NOT EXISTS "${UAVM_SYSROOT}/usr/include/aarch64-linux-gnu")
  message(FATAL_ERROR "no arm64 sysroot at ${UAVM_SYSROOT}: run scripts/make_sysroot.sh")
endif()
# try_compile projects see only what is listed here.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES UAVM_SYSROOT UAVM_AARCH64_CPU)

set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
set(CMAKE_SYSROOT "${UAVM_SYSROOT}")
set(CMAKE_FIND_ROOT_PATH "${UAVM_SYSROOT}")
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

set(ENV{PKG_CONFIG_SYSROOT_DIR} "${UAVM_SYSROOT}")
set(ENV{PKG_CONFIG_LIBDIR} "${UAVM_SYSROOT}/usr/lib/aarch64-linux-gnu/pkgconfig:${UAVM_SYSROOT}/usr/share/pkgconfig")
set(ENV{PKG_CONFIG_PATH} "")

if(UAVM_AARCH64_CPU)
  set(CMAKE_C_FLAGS_INIT "-mcpu=${UAVM_AARCH64_CPU}")
  set(CMAKE_CXX_FLAGS_INIT "-mcpu=${UAVM_AARCH64_CPU}")
endif()
# The sysroot's libraries find their own dependencies (liblapack through libopencv, ...) at link time.
set(CMAKE_EXE_LINKER_FLAGS_INIT "-Wl,-rpath-link,${UAVM_SYSROOT}/usr/lib/aarch64-linux-gnu -Wl,-rpath-link,${UAVM_SYSROOT}/lib/aarch64-linux-gnu")

# -L: the emulated binaries load the sysroot's dynamic loader and libraries.
# Through env: the programs a test starts itself (exec of an aarch64 binary, through binfmt_misc, see
# scripts/binfmt_aarch64.sh) find the sysroot's libraries too, and tests know they run emulated (tests/test_env.h).
set(CMAKE_CROSSCOMPILING_EMULATOR "env;UAVM_EMULATED=1;QEMU_LD_PREFIX=${UAVM_SYSROOT};qemu-aarch64;-L;${UAVM_SYSROOT}")
