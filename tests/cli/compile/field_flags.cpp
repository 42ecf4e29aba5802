// The program binds each flag by the field it sets (examples/anisocap/commands/field_flags.hpp):
// built as field_flags_known this compiles and prints the flags; built as field_flags_misspelt
// (MISSPELT) it names a field no table has and must not compile (tests/CMakeLists.txt).
#include <cstdio>

#include "commands/field_flags.hpp"

int main() {
  using namespace anisocap::commands;
  std::printf("%s %s %s\n", capture_flag("finetune_options::learning_rate"), train_flag("train_options::lr_end"),
              flag_of(batch_field_flags, "batch_selection::count"));
#ifdef MISSPELT
  std::printf("%s\n", capture_flag("finetune_options::learning_rates"));
#endif
}
