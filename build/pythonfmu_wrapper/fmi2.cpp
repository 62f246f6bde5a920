
#include "Logger.hpp"
#include "SlaveInstance.hpp"
#include "fmi2Functions.h"
#include "fmu_except.hpp"

#include <algorithm>
#include <cctype>
#include <string>
#include <cstdio>
#include <iterator>
#include <exception>
#include <memory>
#include <optional>
#include <set>

namespace
{

class Fmi2Logger : public pythonfmu::PyLogger
{

public:
    explicit Fmi2Logger(const std::string& instanceName, const fmi2CallbackFunctions* f)
        : PyLogger(instanceName)
        , f_(f)
    { }

protected:
    void debugLog(fmi2Status s, const std::string& category, const std::string& message) override
    {
        if (f_ == nullptr || f_->logger == nullptr) return;   // LMNCell: no logger, no call
        // LMNCell: the message is an argument, never the format (a '%' in it, say from a path or
        // a Python exception, would be read as a conversion by the host's printf-style logger),
        // and an empty category becomes the declared logStatus… category of the status
        f_->logger(f_->componentEnvironment, instanceName_.c_str(), s,
            category.empty() ? statusCategory(s) : category.c_str(), "%s", message.c_str());
    }

    static const char* statusCategory(fmi2Status s)
    {
        switch (s) {
            case fmi2Warning: return "logStatusWarning";
            case fmi2Discard: return "logStatusDiscard";
            case fmi2Error: return "logStatusError";
            case fmi2Fatal: return "logStatusFatal";
            default: return "logAll";
        }
    }

private:
    const fmi2CallbackFunctions* f_;
};

// A struct that holds all the data for one model instance.
struct Fmi2Component
{

    Fmi2Component(std::unique_ptr<pythonfmu::SlaveInstance> slave, std::unique_ptr<Fmi2Logger> logger)
        : slave(std::move(slave))
        , logger(std::move(logger))
    { }

    bool wantsToTerminate{false};
    // LMNCell: the FMU states this instance handed out (fmi2GetFMUstate,
    // fmi2DeSerializeFMUstate) and not yet freed: only these are taken back, and
    // fmi2FreeInstance frees what is left
    std::set<fmi2FMUstate> states;

    std::unique_ptr<pythonfmu::SlaveInstance> slave;
    std::unique_ptr<Fmi2Logger> logger;
};

} // namespace


// FMI functions
extern "C" {

// =============================================================================
// FMI 2.0 functions
// =============================================================================


const char* fmi2GetTypesPlatform()
{
    return fmi2TypesPlatform;
}


namespace
{

std::string lower_case(std::string text)
{
    for (auto& ch : text) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    return text;
}

int hex_digit(char ch)
{
    if (ch >= '0' && ch <= '9') return ch - '0';
    if (ch >= 'a' && ch <= 'f') return ch - 'a' + 10;
    if (ch >= 'A' && ch <= 'F') return ch - 'A' + 10;
    return -1;
}

// LMNCell: the local path of the resources folder from fmuResourceLocation. FMI 2.0 (section
// 2.1.5) asks an FMU to take the "file" scheme with an absolute path, with or without the
// authority: "file:///p", "file://localhost/p" and "file:/p" (RFC 8089; the scheme and host
// in any case), each %XX decoded (RFC 3986), a "?" or "#" ending the path. A bare absolute
// path, which some hosts pass, is taken as it is. Anything else: false, the reason in `why`.
bool resource_path(const std::string& uri, std::string& path, std::string& why)
{
    if (!uri.empty() && uri[0] == '/') {
        path = uri;
        return true;
    }
    if (lower_case(uri.substr(0, 5)) != "file:") {
        why = "only file URIs are supported (expected file:///absolute/path/to/resources)";
        return false;
    }
    std::string rest = uri.substr(5);
    if (rest.compare(0, 2, "//") == 0) {
        const auto slash = rest.find('/', 2);
        const auto host = lower_case(rest.substr(2, slash == std::string::npos ? std::string::npos
                                                                                 : slash - 2));
        if (!host.empty() && host != "localhost") {
            why = "the host '" + host.substr(0, 100) + "' is not this machine (expected "
                  "file:///absolute/path or file://localhost/absolute/path)";
            return false;
        }
        rest = slash == std::string::npos ? std::string() : rest.substr(slash);
    }
    rest = rest.substr(0, rest.find_first_of("?#"));
    if (rest.empty() || rest[0] != '/') {
        why = "the path is not absolute (expected file:///absolute/path/to/resources)";
        return false;
    }
    path.clear();
    for (std::size_t k = 0; k < rest.size(); ++k) {
        if (rest[k] != '%') {
            path += rest[k];
            continue;
        }
        const int high = k + 2 < rest.size() ? hex_digit(rest[k + 1]) : -1;
        const int low = k + 2 < rest.size() ? hex_digit(rest[k + 2]) : -1;
        if (high < 0 || low < 0) {
            why = "'%' at character " + std::to_string(k + 1) + " of the path is not followed "
                  "by two hexadecimal digits (expected a percent-encoded URI, e.g. %20 for a "
                  "space)";
            return false;
        }
        if (high == 0 && low == 0) {
            why = "%00 (a NUL character) in the path";
            return false;
        }
        path += static_cast<char>(high * 16 + low);
        k += 2;
    }
#ifdef _WIN32
    // file:///C:/dir names the drive path C:/dir
    if (path.size() >= 3 && path[0] == '/' && path[2] == ':') path.erase(0, 1);
#endif
    return true;
}

// LMNCell: a NULL array with nvr > 0 is the host's mistake: refused (fmi2Error, logged) with
// nothing read or set; the same message as the native FMU's
bool arrays_given(Fmi2Component* component, const char* call, std::size_t n, const void* vr,
    const void* values, const char* done)
{
    if (n == 0 || (vr != nullptr && values != nullptr)) return true;
    component->logger->log(fmi2Error, std::string(call) + ": nvr = " + std::to_string(n) +
        " but " + (vr != nullptr ? "value" : "vr") + " is NULL; nothing was " + done);
    return false;
}

// LMNCell: true where pointer p is given, else logs that the argument `what` of `call` is NULL
bool given(Fmi2Component* component, const char* call, const void* p, const char* what)
{
    if (p != nullptr) return true;
    component->logger->log(fmi2Error, std::string(call) + ": " + what + " is NULL");
    return false;
}

// LMNCell: true where state is a live state of this instance, else logs as the native FMU
// does: a freed or foreign pointer is never read
bool own_state(Fmi2Component* component, const char* call, fmi2FMUstate state)
{
    if (!given(component, call, state, "the FMU state")) return false;
    if (component->states.count(state) > 0) return true;
    component->logger->log(fmi2Error, std::string(call) + ": the FMU state is not one of this "
        "instance's (freed, or from another instance or FMU?)");
    return false;
}

// LMNCell: fresh becomes the host's *state, a state of this instance; the one *state held
// before, if any (a live state, checked by own_state), is freed, as FMI 2.0 lets
// fmi2GetFMUstate and fmi2DeSerializeFMUstate reuse it (pythonfmu leaked it)
void keep_state(Fmi2Component* component, fmi2FMUstate* state, fmi2FMUstate fresh)
{
    if (*state != nullptr) {
        component->states.erase(*state);
        component->slave->FreeFMUstate(*state);
    }
    component->states.insert(fresh);
    *state = fresh;
}

// LMNCell: a status this FMU cannot give: fmi2Discard, as FMI 2.0 asks, with the native FMU's
// message (its steps never return fmi2Pending; an ordinary error returns fmi2Error)
fmi2Status no_status(Fmi2Component* component, const char* call, fmi2StatusKind kind)
{
    static const char* const names[] = {"fmi2DoStepStatus", "fmi2PendingStatus",
        "fmi2LastSuccessfulTime", "fmi2Terminated"};
    const auto k = static_cast<unsigned>(kind);
    component->logger->log(fmi2Discard, std::string(call) + ": no " +
        (k < 4 ? names[k] : "(unknown kind)") + " status (this FMU answers "
        "fmi2LastSuccessfulTime by fmi2GetRealStatus and fmi2Terminated by "
        "fmi2GetBooleanStatus; its steps never return fmi2Pending)");
    return fmi2Discard;
}

// LMNCell: a function this FMU does not offer: fmi2Error with the native FMU's message under
// a declared category (pythonfmu logged under "cppfmu", which no model description declares)
fmi2Status not_supported(fmi2Component c, const char* message)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component != nullptr) component->logger->log(fmi2Error, message);
    return fmi2Error;
}

} // namespace


const char* fmi2GetVersion()
{
    return "2.0";
}


fmi2Component fmi2Instantiate(fmi2String instanceName,
    fmi2Type fmuType,
    fmi2String fmuGUID,
    fmi2String fmuResourceLocation,
    const fmi2CallbackFunctions* functions,
    fmi2Boolean visible,
    fmi2Boolean loggingOn)
{
    // LMNCell: checks before anything is dereferenced; a refusal is logged (when there is a
    // logger) and returns NULL, as the standard asks
    const auto refuse = [&](const std::string& why) -> fmi2Component {
        if (functions != nullptr && functions->logger != nullptr) {
            functions->logger(functions->componentEnvironment,
                instanceName ? instanceName : "", fmi2Error, "logStatusError", "%s", why.c_str());
        }
        return nullptr;
    };
    if (functions == nullptr || functions->logger == nullptr) return nullptr;
    if (instanceName == nullptr || instanceName[0] == '\0') {
        return refuse("fmi2Instantiate: empty instanceName");
    }
    if (fmuType != fmi2CoSimulation) {
        return refuse("fmi2Instantiate: this FMU offers Co-Simulation only, not Model Exchange");
    }
#ifdef LMNCELL_GUID
    if (fmuGUID == nullptr || std::string(fmuGUID) != LMNCELL_GUID) {
        return refuse(std::string("fmi2Instantiate: GUID ") + (fmuGUID ? fmuGUID : "(null)") +
            " is not this FMU's " + LMNCELL_GUID);
    }
#endif
    if (fmuResourceLocation == nullptr || fmuResourceLocation[0] == '\0') {
        return refuse("fmi2Instantiate: no fmuResourceLocation (expected the file URI of the "
                      "FMU's resources folder)");
    }

    // LMNCell: the resources folder from its file URI as FMI 2.0 asks (pythonfmu decoded only
    // %20 and took "file:/p" or "file://localhost/p" as relative paths)
    std::string resources, why;
    if (!resource_path(fmuResourceLocation, resources, why)) {
        return refuse("fmi2Instantiate: fmuResourceLocation '" +
            std::string(fmuResourceLocation).substr(0, 300) + "': " + why);
    }

    auto logger = std::make_unique<Fmi2Logger>(instanceName, functions);
    logger->setDebugLogging(loggingOn);

    try {

        auto instance = pythonfmu::createInstance(
            {logger.get(),
                visible == fmi2True,
                instanceName,
                resources,
                nullptr});

        auto component = std::make_unique<Fmi2Component>(std::move(instance), std::move(logger));
        return component.release();
    } catch (const std::exception& e) {
        logger->log(fmi2Fatal, e.what());
        return nullptr;
    }
}


void fmi2FreeInstance(fmi2Component c)
{
    if (c) {
        const auto component = static_cast<Fmi2Component*>(c);
        for (auto state : component->states) {   // LMNCell: the states the host left
            try {
                component->slave->FreeFMUstate(state);
            } catch (const std::exception&) {
            }
        }
        delete component;
    }
}


fmi2Status fmi2SetDebugLogging(
    fmi2Component c,
    fmi2Boolean loggingOn,
    size_t nCategories,
    const fmi2String categories[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash

    // LMNCell: a NULL array or entry is refused (it was a std::string from NULL, an exception
    // out of a C function: the host terminated); the logging stays as it was
    char why[256];
    if (nCategories > 0 && categories == nullptr) {
        std::snprintf(why, sizeof why, "fmi2SetDebugLogging: nCategories = %zu but categories is "
                      "NULL; logging left as it was", nCategories);
        component->logger->log(fmi2Error, why);
        return fmi2Error;
    }
    std::vector<std::string> categoriesVec;
    try {
        categoriesVec.reserve(nCategories);
        for (size_t i = 0; i < nCategories; ++i) {
            if (categories[i] == nullptr) {
                std::snprintf(why, sizeof why, "fmi2SetDebugLogging: nCategories = %zu but "
                              "categories[%zu] is NULL; logging left as it was", nCategories, i);
                component->logger->log(fmi2Error, why);
                return fmi2Error;
            }
            categoriesVec.emplace_back(categories[i]);
        }
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }

    // LMNCell: a category that modelDescription.xml does not declare is ignored with a warning
    // that names it and the declared ones (FMI 2.0: the allowed categories are the FMU's)
    static const char* const declared[] = {"logStatusWarning", "logStatusDiscard",
                                           "logStatusError", "logStatusFatal", "logAll"};
    fmi2Status status = fmi2OK;
    for (const auto& name : categoriesVec) {
        if (std::find(std::begin(declared), std::end(declared), name) == std::end(declared)) {
            std::snprintf(why, sizeof why, "fmi2SetDebugLogging: log category '%.40s' is not "
                          "declared, ignored; this FMU declares logStatusWarning, "
                          "logStatusDiscard, logStatusError, logStatusFatal, logAll",
                          name.c_str());
            component->logger->report(fmi2Warning, why);
            status = fmi2Warning;
        }
    }
    component->logger->setDebugLogging(loggingOn, categoriesVec);

    return status;
}


fmi2Status fmi2SetupExperiment(
    fmi2Component c,
    fmi2Boolean toleranceDefined,
    fmi2Real tolerance,
    fmi2Real startTime,
    fmi2Boolean stopTimeDefined,
    fmi2Real stopTime)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    try {
        component->slave->SetupExperiment(
            startTime,
            stopTimeDefined ? std::optional(stopTime) : std::nullopt,
            toleranceDefined ? std::optional(tolerance) : std::nullopt);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    try {
        component->slave->EnterInitializationMode();
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    try {
        component->slave->ExitInitializationMode();
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2Terminate(fmi2Component c)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    try {
        component->slave->Terminate();
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2Reset(fmi2Component c)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    try {
        component->slave->Reset();
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2GetReal(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    fmi2Real value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2GetReal", nvr, vr, value, "read")) return fmi2Error;
    try {
        component->slave->GetReal(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2GetInteger(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    fmi2Integer value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2GetInteger", nvr, vr, value, "read")) return fmi2Error;
    try {
        component->slave->GetInteger(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2GetBoolean(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    fmi2Boolean value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2GetBoolean", nvr, vr, value, "read")) return fmi2Error;
    try {
        component->slave->GetBoolean(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2GetString(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    fmi2String value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2GetString", nvr, vr, value, "read")) return fmi2Error;
    try {
        component->slave->GetString(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2SetReal(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    const fmi2Real value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2SetReal", nvr, vr, value, "set")) return fmi2Error;
    try {
        component->slave->SetReal(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2SetInteger(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    const fmi2Integer value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2SetInteger", nvr, vr, value, "set")) return fmi2Error;
    try {
        component->slave->SetInteger(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2SetBoolean(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    const fmi2Boolean value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2SetBoolean", nvr, vr, value, "set")) return fmi2Error;
    try {
        component->slave->SetBoolean(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2SetString(
    fmi2Component c,
    const fmi2ValueReference vr[],
    size_t nvr,
    const fmi2String value[])
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!arrays_given(component, "fmi2SetString", nvr, vr, value, "set")) return fmi2Error;
    for (std::size_t k = 0; k < nvr; ++k) {   // LMNCell: a NULL string is not read
        if (value[k] == nullptr) {
            component->logger->log(fmi2Error, "fmi2SetString: value[" + std::to_string(k) +
                "] is NULL; nothing was set");
            return fmi2Error;
        }
    }
    try {
        component->slave->SetString(vr, nvr, value);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2GetFMUstate(
    fmi2Component c,
    fmi2FMUstate* state)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!given(component, "fmi2GetFMUstate", state, "the pointer to the FMU state")) {
        return fmi2Error;   // LMNCell: not written through NULL
    }
    if (*state != nullptr && !own_state(component, "fmi2GetFMUstate", *state)) return fmi2Error;
    try {
        fmi2FMUstate fresh = nullptr;
        component->slave->GetFMUstate(fresh);
        keep_state(component, state, fresh);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2SetFMUstate(
    fmi2Component c,
    fmi2FMUstate state)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!own_state(component, "fmi2SetFMUstate", state)) return fmi2Error;
    try {
        component->slave->SetFMUstate(state);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2FreeFMUstate(
    fmi2Component c,
    fmi2FMUstate* state)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!given(component, "fmi2FreeFMUstate", state, "the pointer to the FMU state")) {
        return fmi2Error;   // LMNCell: not read through NULL
    }
    if (*state == nullptr) return fmi2OK;   // nothing to free
    if (!own_state(component, "fmi2FreeFMUstate", *state)) return fmi2Error;
    try {
        component->states.erase(*state);
        component->slave->FreeFMUstate(*state);
        *state = nullptr;
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2SerializedFMUstateSize(
    fmi2Component c,
    fmi2FMUstate state,
    size_t* size)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!own_state(component, "fmi2SerializedFMUstateSize", state) ||
        !given(component, "fmi2SerializedFMUstateSize", size, "size")) return fmi2Error;
    try {
        *size = component->slave->SerializedFMUstateSize(state);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2SerializeFMUstate(
    fmi2Component c,
    fmi2FMUstate state,
    fmi2Byte bytes[],
    size_t size)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!own_state(component, "fmi2SerializeFMUstate", state) ||
        !given(component, "fmi2SerializeFMUstate", bytes, "serializedState")) return fmi2Error;
    try {
        component->slave->SerializeFMUstate(state, bytes, size);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2DeSerializeFMUstate(
    fmi2Component c,
    const fmi2Byte bytes[],
    size_t size,
    fmi2FMUstate* state)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    if (!given(component, "fmi2DeSerializeFMUstate", bytes, "serializedState") ||
        !given(component, "fmi2DeSerializeFMUstate", state, "the pointer to the FMU state")) {
        return fmi2Error;
    }
    if (*state != nullptr && !own_state(component, "fmi2DeSerializeFMUstate", *state)) {
        return fmi2Error;
    }
    try {
        fmi2FMUstate fresh = nullptr;
        component->slave->DeSerializeFMUstate(bytes, size, fresh);
        keep_state(component, state, fresh);
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}


fmi2Status fmi2GetDirectionalDerivative(
    fmi2Component c,
    const fmi2ValueReference[],
    size_t,
    const fmi2ValueReference[],
    size_t,
    const fmi2Real[],
    fmi2Real[])
{
    return not_supported(c, "fmi2GetDirectionalDerivative: not supported "
                                "(providesDirectionalDerivative is false)");
}

fmi2Status fmi2SetRealInputDerivatives(
    fmi2Component c,
    const fmi2ValueReference[],
    size_t,
    const fmi2Integer[],
    const fmi2Real[])
{
    return not_supported(c, "fmi2SetRealInputDerivatives: not supported "
                                "(canInterpolateInputs is false)");
}

fmi2Status fmi2GetRealOutputDerivatives(
    fmi2Component c,
    const fmi2ValueReference[],
    size_t,
    const fmi2Integer[],
    fmi2Real[])
{
    return not_supported(c, "fmi2GetRealOutputDerivatives: not supported "
                                "(maxOutputDerivativeOrder is 0)");
}

fmi2Status fmi2DoStep(
    fmi2Component c,
    fmi2Real currentCommunicationPoint,
    fmi2Real communicationStepSize,
    fmi2Boolean /*noSetFMUStatePriorToCurrentPoint*/)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;   // LMNCell: no instance, no crash
    try {
        const auto ok = component->slave->DoStep(
            currentCommunicationPoint,
            communicationStepSize);
        if (ok) {
            return fmi2OK;
        }

        component->wantsToTerminate = true;
        return fmi2Discard;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    return not_supported(c, "fmi2CancelStep: not supported "
                                "(its steps never return fmi2Pending)");
}


/* Inquire slave status (LMNCell: as the native FMU; pythonfmu returned fmi2Error for
   fmi2GetStatus, NaN as the last successful time before a step, and wrote through NULL) */
fmi2Status fmi2GetStatus(
    fmi2Component c,
    const fmi2StatusKind s,
    fmi2Status*)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;
    return no_status(component, "fmi2GetStatus", s);
}

// fmi2LastSuccessfulTime: the end of the last completed communication step (the start time
// before the first), the slave's own time
fmi2Status fmi2GetRealStatus(
    fmi2Component c,
    const fmi2StatusKind s,
    fmi2Real* value)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return no_status(component, "fmi2GetRealStatus", s);
    if (!given(component, "fmi2GetRealStatus", value, "value")) return fmi2Error;
    try {
        *value = component->slave->LastSuccessfulTime();
        return fmi2OK;
    } catch (const pythonfmu::fatal_error& e) {
        component->logger->log(fmi2Fatal, e.what());
        return fmi2Fatal;
    } catch (const std::exception& e) {
        component->logger->log(fmi2Error, e.what());
        return fmi2Error;
    }
}

fmi2Status fmi2GetIntegerStatus(
    fmi2Component c,
    const fmi2StatusKind s,
    fmi2Integer*)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;
    return no_status(component, "fmi2GetIntegerStatus", s);
}

// fmi2Terminated: whether a discarded step asked to end the simulation (never, with LMNCell's
// slave, which refuses a bad step with fmi2Error)
fmi2Status fmi2GetBooleanStatus(
    fmi2Component c,
    const fmi2StatusKind s,
    fmi2Boolean* value)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;
    if (s != fmi2Terminated) return no_status(component, "fmi2GetBooleanStatus", s);
    if (!given(component, "fmi2GetBooleanStatus", value, "value")) return fmi2Error;
    *value = component->wantsToTerminate ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(
    fmi2Component c,
    const fmi2StatusKind s,
    fmi2String*)
{
    const auto component = static_cast<Fmi2Component*>(c);
    if (component == nullptr) return fmi2Error;
    return no_status(component, "fmi2GetStringStatus", s);
}
}
