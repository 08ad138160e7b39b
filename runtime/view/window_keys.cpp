// The window's keys: one table for the help, --help and the docs (window_keys.h).
#include "runtime/view/window_keys.h"

#include <algorithm>
#include <cstring>

namespace heartsim {

const std::vector<WindowKey>& window_keys() {
    static const std::vector<WindowKey> keys = {
        {"left drag", "orbit", "horizontal about the view's up axis (superior for the default view), vertical about the camera's right axis"},
        {"right or middle drag, Shift + left drag", "pan", "moves the orbit centre in the view plane"},
        {"wheel", "zoom", "0.05 to 20 model radii"},
        {"R", "reset the view", "back to the fitted default view (--view)"},
        {"C", "section view on / off", "cuts the heart open: a plane through its centre facing the view hides the nearer half, the cut wall shows flat dark red, instruments stay whole; the HUD says where the plane is (also --clip)"},
        {"[ / ]", "move the section", "the plane 1 mm back / deeper along its normal (Shift: 5 mm; held: repeats); the terminal says where it is"},
        {"V", "aim the section at the view", "turns the plane to face the current view, at the same depth from the heart's centre"},
        {"arrows", "move instrument 0", "in the view plane, 0.25 model radius per second of the wall clock whatever the frame rate (the terminal gives it in mm/s at the start; Shift: 5x slower); each press counts, a tap as 0.1 s held; the mouse device with --device mouse", KeyNeeds::moving_keys},
        {"PgUp / PgDn", "move instrument 0 in depth", "into / out of the screen, at the arrows' speed", KeyNeeds::moving_keys},
        {"Space", "pause / resume", "the simulation stops (rendering and the camera go on); paused time is not owed afterwards"},
        {"N", "one step while paused", "advances the paused simulation by one time step (not with --device)", KeyNeeds::no_device},
        {"T", "reset the tissue", "back to its rest state (grabs released, what retractors left anchored free again; the simulated time and the instruments go on); not while a recording runs (F5 or --record): a replay could not repeat it"},
        {"P", "screenshot", "the window as seen (HUD included) to SCENARIO-YYYYmmdd-HHMMSS.png beside the scenario; the path is printed"},
        {"K", "scalpel on / off", "with --device: instrument 0 becomes a scalpel (a 20 mm blade from the tip along the tool's +z; G or button 1 lowers it and it cuts what it sweeps), K again gives back its own (--instrument's); a button held through the switch acts at its next press; a recording keeps the switch", KeyNeeds::device},
        {"Shift + P", "patch on / off", "with --device: instrument 0 becomes a patch of --patch-material, a disc reaching 4 mm beyond the defect's edge (18 mm across without a defect), 0.5 mm thick; with the mouse device it faces into the screen; G or button 1 lays it on the tissue in front of it, held there until its first stitch; Shift + P again gives back its own instrument; a recording keeps the switch", KeyNeeds::device},
        {"Shift + N", "needle on / off", "with --device: instrument 0 becomes a needle; G or button 1 ties a stitch from the tissue at its tip (within 5 mm) to the laid patch's point nearest it, drawn tight over 150 ms, and the hand feels the suture while the button is held; Shift + N again gives back its own instrument; a recording keeps the switch", KeyNeeds::device},
        {"F5", "start / stop recording", "with --device (not with --record): resets the tissue to rest (as T) and records from there; F5 again writes SCENARIO-YYYYmmdd-HHMMSS.rec.h5 beside the scenario for --replay; the path is printed", KeyNeeds::device},
        {"F2 or Tab", "HUD on / off", "the case, its septal defect if it has one and the procedure (I adds the figures), each hand's device, instrument and force, a laid patch and its stitches (with a defect: whether it closes it, checked once a second, and where it leaks, marked by a cyan ball), axes, scale bar"},
        {"H or F1", "help on / off", "this table in the window, the keys that work in the session"},
        {"I", "figures on / off", "the HUD's figures: real-time factor, fps, steps/s, simulated time, particles, backend, mass scale, a haptic session's device period; without them the HUD says when the simulation runs slower than real time"},
        {"E", "emergency stop", "with --device: every device's force to zero, latched until E again (a red banner says so)", KeyNeeds::device},
        {"G", "mouse device button 1", "with --device mouse: a grabber holds, a scalpel (--instrument scalpel) cuts, while it is on; a patch is laid, a needle ties a stitch, as it turns on", KeyNeeds::mouse_device},
        {"Ctrl + left drag", "move the mouse device", "with --device mouse: in the view plane, one pixel per pixel at the orbit centre's depth", KeyNeeds::mouse_device},
        {"Ctrl + wheel", "mouse device in depth", "with --device mouse: wheel up moves it into the screen (2 % of the model radius a notch)", KeyNeeds::mouse_device},
        {"Ctrl + Shift + left click or drag", "mouse device onto the surface", "with --device mouse: onto the tissue's surface point under the cursor, its centre a quarter of its extent below it (it rests on it, the tissue pushing back with a few mN; drawn amber from 0.01 N, which Ctrl + wheel presses it to; a scalpel's or needle's tip on it, a patch 2 mm in front of it); dragged, it slides along the surface; over the background it stays where it is", KeyNeeds::mouse_device},
        {"Ctrl + right click", "mouse device button 1", "with --device mouse: as G (a grabber closes on the tissue it touches, or lets go)", KeyNeeds::mouse_device},
        {"Esc, closing the window", "quit", "the state file, the stats, --record and an F5 recording that is on are still written"},
    };
    return keys;
}

bool key_works(const WindowKey& key, const WindowKeySession& session) {
    switch (key.needs) {
    case KeyNeeds::always: return true;
    case KeyNeeds::moving_keys: return session.keyboard_instrument || session.mouse_device;
    case KeyNeeds::no_device: return !session.device;
    case KeyNeeds::device: return session.device;
    case KeyNeeds::mouse_device: return session.mouse_device;
    }
    return true;
}

std::string window_keys_markdown() {
    std::string out = "| input | action | details |\n|---|---|---|\n";
    for (const WindowKey& k : window_keys()) out += std::string("| ") + k.input + " | " + k.action + " | " + k.description + " |\n";
    return out;
}

std::string window_keys_text() {
    std::size_t width = 0;
    for (const WindowKey& k : window_keys()) width = std::max(width, std::strlen(k.input));
    std::string out = "Window keys and mouse (also on screen: H):\n";
    for (const WindowKey& k : window_keys()) {
        std::string input = k.input;
        input.resize(width, ' ');
        out += "  " + input + "  " + k.action + ": " + k.description + "\n";
    }
    return out;
}

}  // namespace heartsim
