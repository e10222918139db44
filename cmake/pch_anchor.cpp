// The one source of the precompiled-header targets (cmake/UavmPch.cmake): CMake compiles a PCH for a target that has
// a source; this file holds nothing else.
