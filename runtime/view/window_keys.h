/// @file window_keys.h
/// @brief The window's keys and mouse actions, in one table: the window's on-screen help (H),
/// `heartsim run --help`'s footer and docs/runtime.md "Window mode" are all made from it (a test
/// compares the document's table with window_keys_markdown()).
#pragma once

#include <string>
#include <vector>

namespace heartsim {

/// Which sessions a key works in (the window's help lists only those of its session).
enum class KeyNeeds {
    always,
    moving_keys,   ///< a keyboard instrument (no --device, no --trajectory) or the mouse device
    no_device,     ///< no --device (the simulation's own clock)
    device,        ///< any --device (a haptic session)
    mouse_device,  ///< --device mouse
};

/// One row of the table.
struct WindowKey {
    const char* input;        ///< the key or mouse action, e.g. "Space", "Ctrl + left drag"
    const char* action;       ///< what it does, a few words
    const char* description;  ///< when it applies and the details, one sentence
    KeyNeeds needs = KeyNeeds::always;
};

/// What a window session has, for the keys that work in it.
struct WindowKeySession {
    bool keyboard_instrument = false;  ///< the keyboard moves hand 0 (no --device, no --trajectory)
    bool device = false;               ///< a haptic session (--device)
    bool mouse_device = false;         ///< --device mouse
};

/// Every key and mouse action of the window, in the order the help shows them.
const std::vector<WindowKey>& window_keys();

/// Whether `key` works in `session`.
bool key_works(const WindowKey& key, const WindowKeySession& session);

/// The table as Markdown (`| input | action | details |` with its separator row), one row a line,
/// ending in a newline: exactly what docs/runtime.md holds between its window-keys markers.
std::string window_keys_markdown();

/// The table as plain text for a terminal (`heartsim run --help`'s footer): a heading line, then
/// "  INPUT  action: details" per row, wrapped at no width.
std::string window_keys_text();

}  // namespace heartsim
