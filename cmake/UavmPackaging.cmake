# Install layout and the .debs (CPack), one per install component, for the architecture being built (amd64 natively,
# arm64 with toolchains/aarch64-linux-gnu.cmake); `cmake --build B --target package` (or `cpack` in B) writes both:
#   onboard -> uavmosaic_<version>_<arch>.deb: what the drone's computer runs: uavmosaic-onboard, its video module,
#              /etc/uavmosaic/onboard.yaml, /etc/default/uavmosaic-onboard, the systemd unit, and the simulator and
#              evaluator a field check uses (uavmosaic-sim, uavmosaic-eval);
#   ground  -> uavmosaic-ground_<version>_<arch>.deb: the ground tool (offline 3-D), for the ground station.
# `cpack -D CPACK_COMPONENTS_ALL=onboard` writes the drone's package alone, from a tree that did not build the ground
# tool (the CI tier's aarch64 build: scripts/test_aarch64.sh).
include(GNUInstallDirs)

set(UAVM_MEMORY_BUDGET_MIB 256 CACHE STRING "Memory budget in the packaged config, MiB")
set(UAVM_SERVICE_MEMORY_MAX_MIB "" CACHE STRING "MemoryMax= of the systemd unit, MiB (empty: budget + 25 %)")
set(UAVM_SERVICE_WATCHDOG_SEC 30 CACHE STRING "WatchdogSec= of the systemd unit")
if(NOT UAVM_SERVICE_MEMORY_MAX_MIB)
  # Headroom over the budget: the program's own peaks stay within it (bench/memory.sh), the kernel's accounting of
  # page cache and thread stacks does not.
  math(EXPR UAVM_SERVICE_MEMORY_MAX_MIB "${UAVM_MEMORY_BUDGET_MIB} + ${UAVM_MEMORY_BUDGET_MIB} / 4")
endif()

# The package installs under /usr whatever CMAKE_INSTALL_PREFIX a developer's `cmake --install` uses.
set(UAVM_PACKAGE_PREFIX /usr)
set(UAVM_PACKAGE_BINDIR ${UAVM_PACKAGE_PREFIX}/${CMAKE_INSTALL_BINDIR})
set(UAVM_PACKAGE_DOCDIR ${UAVM_PACKAGE_PREFIX}/share/doc/uavmosaic)
set(UAVM_SYSTEMD_UNIT_DIR "lib/systemd/system" CACHE STRING "Where the unit is installed, relative to the prefix root")
configure_file(${PROJECT_SOURCE_DIR}/packaging/onboard.yaml.in ${PROJECT_BINARY_DIR}/packaging/onboard.yaml @ONLY)
configure_file(${PROJECT_SOURCE_DIR}/packaging/uavmosaic-onboard.service.in
               ${PROJECT_BINARY_DIR}/packaging/uavmosaic-onboard.service @ONLY)
# /etc and /lib are absolute on the target whatever the prefix (/usr for the package).
install(FILES ${PROJECT_BINARY_DIR}/packaging/onboard.yaml DESTINATION /etc/uavmosaic COMPONENT onboard)
install(FILES ${PROJECT_SOURCE_DIR}/packaging/default.env DESTINATION /etc/default RENAME uavmosaic-onboard
        COMPONENT onboard)
install(FILES ${PROJECT_BINARY_DIR}/packaging/uavmosaic-onboard.service DESTINATION /${UAVM_SYSTEMD_UNIT_DIR}
        COMPONENT onboard)
install(FILES ${PROJECT_SOURCE_DIR}/README.md DESTINATION share/doc/uavmosaic COMPONENT onboard)

if(CMAKE_SYSTEM_PROCESSOR MATCHES "^(aarch64|arm64)$")
  set(UAVM_DEB_ARCH arm64)
elseif(CMAKE_SYSTEM_PROCESSOR MATCHES "^(x86_64|AMD64|amd64)$")
  set(UAVM_DEB_ARCH amd64)
else()
  set(UAVM_DEB_ARCH ${CMAKE_SYSTEM_PROCESSOR})
endif()

set(CPACK_GENERATOR DEB)
set(CPACK_DEB_COMPONENT_INSTALL ON)
set(CPACK_COMPONENTS_ALL onboard ground)
set(CPACK_PACKAGE_NAME uavmosaic)
set(CPACK_DEBIAN_ONBOARD_PACKAGE_NAME uavmosaic)
set(CPACK_DEBIAN_GROUND_PACKAGE_NAME uavmosaic-ground)
set(CPACK_DEBIAN_GROUND_DESCRIPTION
    "Ground tool of uavmosaic: camera model, triangulation, bundle adjustment, dense matching and DSM from a flight")
set(CPACK_PACKAGE_VENDOR uavmosaic)
set(CPACK_PACKAGE_CONTACT "uavmosaic maintainers <maintainers@uavmosaic.invalid>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "Onboard drone mapping: registers camera frames into a mosaic during the flight")
set(CPACK_PACKAGING_INSTALL_PREFIX ${UAVM_PACKAGE_PREFIX})
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_ARCHITECTURE ${UAVM_DEB_ARCH})
set(CPACK_DEBIAN_PACKAGE_SECTION science)
# Debian 12's runtime packages of what the binaries link (the same for amd64 and arm64; dpkg-shlibdeps cannot read
# an extract-variant sysroot, so the list is written out, and the package test checks it resolves).
set(CPACK_DEBIAN_PACKAGE_DEPENDS
    "libc6 (>= 2.36), libstdc++6 (>= 12), libgcc-s1, libopencv-core406, libopencv-imgproc406, libopencv-imgcodecs406, \
libopencv-features2d406, libopencv-flann406, libopencv-calib3d406, libopencv-video406, libopencv-videoio406, libopencv-stitching406, \
libgdal32, libexiv2-27, libjpeg62-turbo, libdeflate0, zlib1g, libyaml-cpp0.7, libspdlog1.10, libfmt9, libsystemd0, \
libgoogle-glog0v6, libcholmod3, libcxsparse3, libatlas3-base")
if(UAVM_WITH_LIBCAMERA)  # the libcamera capture back-end (hal/libcamera) is built in
  string(APPEND CPACK_DEBIAN_PACKAGE_DEPENDS ", libcamera0.0.3")
endif()
if(UAVM_WITH_GPSD)  # --telemetry gpsd:HOST:PORT (hal/telemetry/gpsd_source.cpp) links libgps
  string(APPEND CPACK_DEBIAN_PACKAGE_DEPENDS ", libgps28")
endif()
if(UAVM_WITH_LENSFUN)  # the camera database of core/lens/lens_database.cpp (the library and its data)
  string(APPEND CPACK_DEBIAN_PACKAGE_DEPENDS ", liblensfun1, liblensfun-data-v1")
endif()
# The live view (firmware_app/live_server.cpp; its HTTPS and MAVLink signing link OpenSSL) and the Leaflet files each
# session's index.html uses.
string(APPEND CPACK_DEBIAN_PACKAGE_DEPENDS ", libcpp-httplib0.11, libssl3, libjs-leaflet")
# The conffiles dpkg keeps when the operator edited them.
file(WRITE ${PROJECT_BINARY_DIR}/packaging/conffiles "/etc/uavmosaic/onboard.yaml\n/etc/default/uavmosaic-onboard\n")
set(CPACK_DEBIAN_ONBOARD_PACKAGE_CONTROL_EXTRA ${PROJECT_BINARY_DIR}/packaging/conffiles
    ${PROJECT_SOURCE_DIR}/packaging/postinst ${PROJECT_SOURCE_DIR}/packaging/prerm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
# Both packages take CPACK_DEBIAN_PACKAGE_DEPENDS (CPack's default for a component): a superset for either binary;
# the package test checks every binary of both against it.
set(CPACK_STRIP_FILES ON)  # the package carries stripped binaries; the build tree keeps the symbols
include(CPack)
