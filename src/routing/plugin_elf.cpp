#include "routing/plugin_elf.h"

#include <elf.h>
#include <link.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <vector>

#include "mavbond/plugin.h"

namespace mavbond {
namespace {

using Ehdr = ElfW(Ehdr);
using Shdr = ElfW(Shdr);
using Sym = ElfW(Sym);

#if __ELF_NATIVE_CLASS == 64
constexpr unsigned char kClass = ELFCLASS64;
#else
constexpr unsigned char kClass = ELFCLASS32;
#endif
#if __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
constexpr unsigned char kData = ELFDATA2LSB;
#else
constexpr unsigned char kData = ELFDATA2MSB;
#endif
// This build's machine; another is a plugin built for another architecture (an amd64 build
// tree's plugins copied to a Pi). EM_NONE: not known here, left to dlopen.
#if defined(__x86_64__)
constexpr uint16_t kMachine = EM_X86_64;
#elif defined(__aarch64__)
constexpr uint16_t kMachine = EM_AARCH64;
#elif defined(__arm__)
constexpr uint16_t kMachine = EM_ARM;
#elif defined(__i386__)
constexpr uint16_t kMachine = EM_386;
#else
constexpr uint16_t kMachine = EM_NONE;
#endif

// Bounds on what is read of a file no one vouched for as an ELF file yet.
constexpr size_t kMaxSections = 1024;
constexpr uint64_t kMaxTableBytes = 16u << 20;
constexpr size_t kMaxNameLen = 64;

std::string machine_name(uint16_t m) {
    switch (m) {
    case EM_X86_64: return "x86-64 (amd64)";
    case EM_AARCH64: return "AArch64 (arm64)";
    case EM_ARM: return "ARM (armhf)";
    case EM_386: return "i386";
    default: return "machine " + std::to_string(m);
    }
}

class ElfFile {
public:
    ElfFile(int fd, const std::string& path) : fd_(fd), path_(path) {}

    Result<PluginIdentity> identity();

private:
    Error fail(const std::string& why) const { return make_error(path_ + ": " + why); }
    /// Exactly `len` bytes at `offset`, within the file.
    bool read_at(uint64_t offset, void* out, uint64_t len) const {
        if (offset > size_ || len > size_ - offset)
            return false;
        auto* p = static_cast<char*>(out);
        while (len > 0) {
            ssize_t n = pread(fd_, p, len, static_cast<off_t>(offset));
            if (n <= 0)
                return false;
            p += n;
            offset += static_cast<uint64_t>(n);
            len -= static_cast<uint64_t>(n);
        }
        return true;
    }
    /// The bytes of a defined data symbol, from the section that holds them.
    bool symbol_bytes(const Sym& sym, std::vector<char>& out) const;

    int fd_;
    const std::string& path_;
    uint64_t size_ = 0;
    std::vector<Shdr> sections_;
};

bool ElfFile::symbol_bytes(const Sym& sym, std::vector<char>& out) const {
    if (sym.st_shndx == SHN_UNDEF || sym.st_shndx >= sections_.size())
        return false;
    const Shdr& s = sections_[sym.st_shndx];
    if (s.sh_type == SHT_NOBITS || sym.st_value < s.sh_addr ||
        sym.st_value - s.sh_addr > s.sh_size || sym.st_size > s.sh_size - (sym.st_value - s.sh_addr))
        return false;
    out.resize(sym.st_size);
    return read_at(s.sh_offset + (sym.st_value - s.sh_addr), out.data(), sym.st_size);
}

Result<PluginIdentity> ElfFile::identity() {
    struct stat st {};
    if (fstat(fd_, &st) < 0)
        return fail(strerror(errno));
    size_ = static_cast<uint64_t>(st.st_size);
    Ehdr eh{};
    if (!read_at(0, &eh, sizeof eh) || std::memcmp(eh.e_ident, ELFMAG, SELFMAG) != 0)
        return fail("not an ELF file (a plugin is a shared object built against mavbond/plugin.h)");
    if (eh.e_ident[EI_CLASS] != kClass || eh.e_ident[EI_DATA] != kData)
        return fail(std::string("built for ") + (eh.e_ident[EI_CLASS] == ELFCLASS64 ? "64" : "32") +
                    "-bit, this mavbond is " + (kClass == ELFCLASS64 ? "64" : "32") +
                    "-bit: use the plugins built with it");
    if (kMachine != EM_NONE && eh.e_machine != kMachine)
        return fail("built for " + machine_name(eh.e_machine) + ", this mavbond runs on " +
                    machine_name(kMachine) + ": use the plugins built with it");
    if (eh.e_type != ET_DYN)
        return fail("not a shared object");
    if (eh.e_shentsize != sizeof(Shdr) || eh.e_shnum == 0 || eh.e_shnum > kMaxSections)
        return fail("its section table cannot be read (stripped of it?)");
    sections_.resize(eh.e_shnum);
    if (!read_at(eh.e_shoff, sections_.data(), sizeof(Shdr) * eh.e_shnum))
        return fail("its section table lies past the end of the file");

    const Shdr* dynsym = nullptr;
    for (const Shdr& s : sections_) {
        if (s.sh_type == SHT_DYNSYM)
            dynsym = &s;
    }
    if (!dynsym || dynsym->sh_link >= sections_.size() || dynsym->sh_entsize != sizeof(Sym) ||
        dynsym->sh_size > kMaxTableBytes || sections_[dynsym->sh_link].sh_size > kMaxTableBytes)
        return fail("no readable dynamic symbol table");
    const Shdr& strtab = sections_[dynsym->sh_link];
    std::vector<Sym> syms(dynsym->sh_size / sizeof(Sym));
    std::vector<char> names(strtab.sh_size + 1, '\0');  // one NUL more: every name ends
    if (!read_at(dynsym->sh_offset, syms.data(), syms.size() * sizeof(Sym)) ||
        !read_at(strtab.sh_offset, names.data(), strtab.sh_size))
        return fail("its dynamic symbol table lies past the end of the file");

    const Sym* entry = nullptr;
    const Sym* abi = nullptr;
    const Sym* name = nullptr;
    for (const Sym& s : syms) {
        const unsigned bind = ELF64_ST_BIND(s.st_info);
        if (s.st_shndx == SHN_UNDEF || s.st_name >= strtab.sh_size ||
            (bind != STB_GLOBAL && bind != STB_WEAK))
            continue;
        const char* n = names.data() + s.st_name;
        if (std::strcmp(n, MAVBOND_PLUGIN_ENTRY_SYMBOL) == 0)
            entry = &s;
        else if (std::strcmp(n, MAVBOND_PLUGIN_ABI_SYMBOL) == 0)
            abi = &s;
        else if (std::strcmp(n, MAVBOND_PLUGIN_NAME_SYMBOL) == 0)
            name = &s;
    }
    if (!entry)
        return fail("no entry symbol " MAVBOND_PLUGIN_ENTRY_SYMBOL " (not a mavbond plugin?)");
    if (!abi)
        return fail("no " MAVBOND_PLUGIN_ABI_SYMBOL " symbol: built for plugin ABI version 4 or "
                    "older, this mavbond speaks version " +
                    std::to_string(MAVBOND_PLUGIN_ABI_VERSION) + ": rebuild the plugin");
    PluginIdentity id;
    std::vector<char> bytes;
    if (abi->st_size != sizeof id.abi_version || !symbol_bytes(*abi, bytes))
        return fail(MAVBOND_PLUGIN_ABI_SYMBOL " is not a 4-byte value in the file");
    std::memcpy(&id.abi_version, bytes.data(), sizeof id.abi_version);
    if (!name || name->st_size < 2 || name->st_size > kMaxNameLen || !symbol_bytes(*name, bytes) ||
        bytes.back() != '\0')
        return fail("no " MAVBOND_PLUGIN_NAME_SYMBOL " symbol holding its name (MAVBOND_PLUGIN_DATA)");
    id.name.assign(bytes.data());
    return id;
}

}  // namespace

Result<PluginIdentity> read_plugin_identity(int fd, const std::string& path) {
    return ElfFile(fd, path).identity();
}

}  // namespace mavbond
