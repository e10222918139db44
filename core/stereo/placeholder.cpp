// Placeholder so the library exists before its first real source; delete when adding sources.
namespace uavm { [[maybe_unused]] static int placeholder_stereo = 0; }
