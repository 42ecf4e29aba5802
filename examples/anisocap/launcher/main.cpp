// The `anisocap` program of a dispatching build (-DANISOCAP_KERNEL_ISAS=...): one executable for
// every x86-64 CPU. The commands are compiled once per instruction set into shared modules
// (anisocap-<isa>.so: every kernel, the CLI and the pipeline, built with -march=<isa>); this small
// launcher, compiled for the x86-64 baseline, asks the CPU which of them it can run, loads the
// best one (or the one --kernel-isa / ANISOCAP_KERNEL_ISA names) and hands it the command line.
//
// Whole modules rather than per-function dispatch: the library is header-only and its kernels are
// templates inlined into everything above them, so the unit that can be compiled per instruction set
// is the program. A module is linked with -Bsymbolic and hidden visibility, and only one is loaded
// into a process, so no inline function compiled for AVX-512 can stand in for the AVX2 one (the
// one-definition rule a static link of several -march builds would break).
#include <dlfcn.h>
#include <limits.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

/// The instruction sets a module can be built for, best first, with the CPU's test for each.
struct isa_entry {
  const char* name;
  const char* description;
  bool (*supported)();
};
const isa_entry known_isas[] = {
    {"x86-64-v4-bf16", "AVX-512 with BF16",
     [] { return __builtin_cpu_supports("x86-64-v4") && __builtin_cpu_supports("avx512bf16"); }},
    {"x86-64-v4", "AVX-512 F/BW/CD/DQ/VL", [] { return bool(__builtin_cpu_supports("x86-64-v4")); }},
    {"x86-64-v3", "AVX2, FMA, BMI2", [] { return bool(__builtin_cpu_supports("x86-64-v3")); }},
    {"x86-64-v2", "SSE4.2, POPCNT", [] { return bool(__builtin_cpu_supports("x86-64-v2")); }},
    {"x86-64", "SSE2", [] { return true; }},
};

/// The folder this executable lies in ("" where /proc/self/exe cannot be read).
std::string executable_folder() {
  char path[PATH_MAX];
  const ssize_t n = ::readlink("/proc/self/exe", path, sizeof path - 1);
  if (n <= 0) return {};
  std::string p(path, std::size_t(n));
  const auto slash = p.rfind('/');
  return slash == std::string::npos ? std::string() : p.substr(0, slash);
}

/// Where the modules are: beside the program in a build tree, `<bin>/<relative>` once installed.
std::string module_path(const std::string& isa) {
  const std::string here = executable_folder();
  const std::string name = "/anisocap-" + isa + ".so";
  for (const std::string& folder : {here + "/anisocap-kernels", here + "/" + ANISOCAP_MODULE_FOLDER}) {
    const std::string candidate = folder + name;
    if (::access(candidate.c_str(), R_OK) == 0) return candidate;
  }
  return {};
}

/// The value of `--kernel-isa X` or `--kernel-isa=X` on the command line (before a lone "--").
const char* requested_isa(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--") == 0) break;
    if (std::strcmp(argv[i], "--kernel-isa") == 0) return i + 1 < argc ? argv[i + 1] : "";
    if (std::strncmp(argv[i], "--kernel-isa=", 13) == 0) return argv[i] + 13;
  }
  if (const char* env = std::getenv("ANISOCAP_KERNEL_ISA"); env && *env) return env;
  return nullptr;
}

/// What this CPU and this installation offer, for error messages.
std::string offer() {
  std::string text;
  for (const isa_entry& isa : known_isas) {
    if (module_path(isa.name).empty()) continue;
    text += std::string("\n  ") + isa.name + " (" + isa.description + "): " + (isa.supported() ? "runs here" : "not on this CPU");
  }
  return text.empty() ? std::string("\n  (none: the installation has no anisocap-<isa>.so beside the program)") : text;
}

}  // namespace

int main(int argc, char** argv) {
  __builtin_cpu_init();
  const char* requested = requested_isa(argc, argv);
  const isa_entry* chosen = nullptr;
  if (requested) {
    for (const isa_entry& isa : known_isas)
      if (std::strcmp(isa.name, requested) == 0) chosen = &isa;
    if (!chosen) {
      std::fprintf(stderr, "anisocap: error: --kernel-isa '%s' is not an instruction set anisocap builds for; this installation has:%s\n",
                   requested, offer().c_str());
      return 2;
    }
    if (!chosen->supported()) {
      std::fprintf(stderr, "anisocap: error: --kernel-isa %s needs %s, which this CPU lacks; this installation has:%s\n", chosen->name,
                   chosen->description, offer().c_str());
      return 2;
    }
    if (module_path(chosen->name).empty()) {
      std::fprintf(stderr, "anisocap: error: --kernel-isa %s: this installation has no %s kernels; it has:%s\n", chosen->name,
                   chosen->name, offer().c_str());
      return 2;
    }
  } else {
    for (const isa_entry& isa : known_isas)
      if (isa.supported() && !module_path(isa.name).empty()) {
        chosen = &isa;
        break;
      }
    if (!chosen) {
      std::fprintf(stderr, "anisocap: error: no kernels of this installation run on this CPU; it has:%s\n", offer().c_str());
      return 2;
    }
  }
  // Captures the program starts itself (`anisocap batch`) run the same kernels.
  ::setenv("ANISOCAP_KERNEL_ISA", chosen->name, 1);
  const std::string path = module_path(chosen->name);
  // RTLD_GLOBAL: Open MPI's own plugins, loaded by MPI_Init, look up libmpi's symbols globally.
  void* module = ::dlopen(path.c_str(), RTLD_NOW | RTLD_GLOBAL);
  if (!module) {
    std::fprintf(stderr, "anisocap: error: cannot load the %s kernels %s: %s\n", chosen->name, path.c_str(), ::dlerror());
    return 2;
  }
  using entry_point = int (*)(int, char**);
  const auto run = reinterpret_cast<entry_point>(::dlsym(module, "anisocap_module_main"));
  if (!run) {
    std::fprintf(stderr, "anisocap: error: %s is not an anisocap module (no anisocap_module_main)\n", path.c_str());
    return 2;
  }
  return run(argc, argv);
}
